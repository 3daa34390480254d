// docs/model.md 5: geometry solver.
#include "engine/model/geometry.hpp"

#include <cmath>
#include <functional>
#include <sstream>

#include "engine/model/config.hpp"

namespace cvt {
namespace {

using Vec2 = Eigen::Vector2d;

Vec2 dir(double psi) { return {std::cos(psi), std::sin(psi)}; }

// The closed belt path of the half centre lines: boundary of the convex hull of the two
// path circles (docs/model.md 5.1), as a signed distance (> 0 outside) and a region label.
struct BeltPath {
  double a, R1, R2, th_up, th_lo;
  Vec2 u_up, u_lo;
  BeltPath(double a_, double R1_, double R2_) : a(a_), R1(R1_), R2(R2_) {
    const double sg = (R2 - R1) / a;
    const double cg = std::sqrt(1 - sg * sg);
    u_up = {-sg, cg};
    u_lo = {-sg, -cg};
    th_up = std::atan2(u_up.y(), u_up.x());               // in (0, pi)
    th_lo = std::atan2(u_lo.y(), u_lo.x()) + 2 * M_PI;     // in (pi, 2 pi)
  }
  int region(const Vec2& c) const {
    double a1 = std::atan2(c.y(), c.x());
    if (a1 < 0) a1 += 2 * M_PI;
    if (a1 >= th_up && a1 <= th_lo) return 0;
    const double a2 = std::atan2(c.y(), c.x() - a);
    if (a2 >= th_lo - 2 * M_PI && a2 <= th_up) return 1;
    return 2;
  }
  double sd(const Vec2& c) const {
    switch (region(c)) {
      case 0: return c.norm() - R1;
      case 1: return (c - Vec2(a, 0)).norm() - R2;
      default: return c.y() >= 0 ? u_up.dot(c) - R1 : u_lo.dot(c) - R1;
    }
  }
  Vec2 span_direction(const Vec2& c) const {
    const Vec2 u = c.y() >= 0 ? u_up : u_lo;
    return {-u.y(), u.x()};  // z x u: counter-clockwise travel
  }
};

// Root of f on [lo, hi] with f(lo), f(hi) of opposite signs (bisection + secant, Illinois).
double solve_bracketed(const std::function<double(double)>& f, double lo, double hi, double tol,
                       int* iters = nullptr) {
  double flo = f(lo), fhi = f(hi);
  int side = 0;
  for (int it = 0; it < 200; ++it) {
    const double x = (lo * fhi - hi * flo) / (fhi - flo);
    const double fx = f(x);
    if (iters) ++*iters;
    if (std::abs(fx) < tol || std::abs(hi - lo) < 1e-15 * (1 + std::abs(x))) return x;
    if ((fx > 0) == (fhi > 0)) {
      hi = x; fhi = fx;
      if (side == -1) flo *= 0.5;
      side = -1;
    } else {
      lo = x; flo = fx;
      if (side == +1) fhi *= 0.5;
      side = +1;
    }
  }
  return 0.5 * (lo + hi);
}

struct Walk {
  std::vector<Vec2> pa, pb;
  std::vector<double> psi;  // link angles psi_0 .. psi_N
  bool ok = true;
};

// Half b of a joint from its half a (held by the previous link, angle psi_prev) and the
// articulation alpha: rocker faces touching with the normal along the bisector (5.2).
Vec2 half_b_from(const Vec2& pa, double psi_prev, double alpha, const ChainPathParams& p) {
  const Vec2 ca = pa - p.kappa * dir(psi_prev);
  const Vec2 cb = ca - 2 * p.rocker_radius * dir(psi_prev + 0.5 * alpha);
  return cb - p.kappa * dir(psi_prev + alpha);
}

// Distance between the two halves of a joint articulated by alpha (5.2).
double half_gap(double alpha, const ChainPathParams& p) {
  return 2 * p.rocker_radius + 2 * p.kappa * std::cos(0.5 * alpha);
}

// Walks N links from joint 0, centred on the leftmost point of the driving arc with
// articulation alpha0. At every joint i the articulation alpha_i is the one that puts the
// leading half a_{i+1} of the next joint on the path of half centre lines (5.2): every
// plate at rest length, every rocker pair just touching, every leading half on the path.
Walk walk(const BeltPath& path, double alpha0, const ChainPathParams& p, int links,
          const std::vector<double>* lift = nullptr) {
  Walk w;
  w.pa.resize(links + 1);
  w.pb.resize(links + 1);
  w.psi.resize(links + 1);
  const double D = half_gap(alpha0, p);
  const double x0 = -std::sqrt(path.R1 * path.R1 - 0.25 * D * D);
  w.pa[0] = {x0, -0.5 * D};
  w.pb[0] = {x0, 0.5 * D};
  w.psi[0] = -M_PI / 2 + 0.5 * alpha0;
  w.pa[1] = w.pb[0] + p.plate_rest * dir(w.psi[0]);
  for (int i = 1; i <= links; ++i) {
    const double psi_prev = w.psi[i - 1];
    auto next_a = [&](double alpha) {
      return Vec2(half_b_from(w.pa[i], psi_prev, alpha, p) + p.plate_rest * dir(psi_prev + alpha));
    };
    const double target = lift ? (*lift)[(i + 1) % links] : 0.0;
    auto f = [&](double alpha) { return path.sd(next_a(alpha)) - target; };
    const double lo = -0.5, hi = 1.5;
    if (!((f(lo) > 0) && (f(hi) < 0))) { w.ok = false; return w; }
    const double alpha = solve_bracketed(f, lo, hi, 1e-15);
    w.pb[i] = half_b_from(w.pa[i], psi_prev, alpha, p);
    w.psi[i] = psi_prev + alpha;
    if (i < links) w.pa[i + 1] = next_a(alpha);
  }
  return w;
}

// Articulation of the regular polygon on the driving arc: the plate from b_0 lands a_1
// on the same circle.
double regular_alpha(const BeltPath& path, const ChainPathParams& p, double lift1 = 0.0) {
  auto g = [&](double alpha0) {
    const double D = half_gap(alpha0, p);
    const double x0 = -std::sqrt(path.R1 * path.R1 - 0.25 * D * D);
    const Vec2 a1 = Vec2(x0, 0.5 * D) + p.plate_rest * dir(-M_PI / 2 + 0.5 * alpha0);
    return path.sd(a1) - lift1;
  };
  return solve_bracketed(g, 1e-6, 1.5, 1e-15);
}

std::string fmt(double v) { std::ostringstream s; s.precision(6); s << v; return s.str(); }

}  // namespace

ChainPathParams chain_path_params(const Config& cfg) {
  ChainPathParams gp;
  gp.centre_distance = cfg.geometry.centre_distance;
  gp.ratio = cfg.geometry.ratio;
  gp.links = cfg.chain.links;
  gp.plate_rest = cfg.chain.pitch + cfg.rocker.half_distance;
  gp.kappa = 0.5 * cfg.rocker.half_distance - cfg.rocker.radius;
  gp.rocker_radius = cfg.rocker.radius;
  gp.r_min = cfg.sheave.hub_radius + 0.5 * cfg.chain.pitch;
  gp.r_max = cfg.sheave.outer_radius - 0.5 * cfg.chain.pitch;
  // A pitch that leaves the joints no radius between the hub and the rim (half a pitch
  // from each): no ratio can fit, and the pitch is what to change.
  if (!(gp.r_min < gp.r_max))
    throw ConfigError("chain.pitch", fmt(cfg.chain.pitch),
                      "too long for the pulleys: the joints need half a pitch above sheave.hub_radius = " +
                          fmt(cfg.sheave.hub_radius) + " m and below sheave.outer_radius = " +
                          fmt(cfg.sheave.outer_radius) + " m, so the pitch must be below " +
                          fmt(cfg.sheave.outer_radius - cfg.sheave.hub_radius) + " m");
  return gp;
}

bool chain_fits(const ChainPathParams& p) {
  const double a = p.centre_distance, i = p.ratio;
  if (!(i > 0)) return false;
  const double R1_lo = std::max(p.r_min, p.r_min / i);
  const double R1_hi = std::min(p.r_max, p.r_max / i);
  if (R1_lo >= R1_hi || std::abs(i * R1_lo - R1_lo) >= a) return false;
  // The closure of place_chain at both ends of the admissible radii: the chain must turn
  // at least 2 pi at the smallest and at most 2 pi at the largest.
  const std::vector<double> lift(p.links + 1, 0.0);
  const auto closure = [&](double R1) {
    BeltPath path(a, R1, i * R1);
    Walk w = walk(path, regular_alpha(path, p), p, p.links, &lift);
    return w.ok ? w.psi[p.links] - w.psi[0] - 2 * M_PI : std::nan("");
  };
  const double f_lo = closure(R1_lo), f_hi = closure(R1_hi * (1 - 1e-9));
  return f_lo >= 0 && f_hi <= 0;  // false for NaN
}

ChainPlacement place_chain(const ChainPathParams& p) {
  const double a = p.centre_distance;
  const int N = p.links;
  const double i = p.ratio;
  // Admissible driving radius range from both pulleys' radius limits (5.1).
  const double R1_lo = std::max(p.r_min, p.r_min / i);
  const double R1_hi = std::min(p.r_max, p.r_max / i);
  if (!(i > 0) || R1_lo >= R1_hi)
    throw ConfigError("geometry.ratio", fmt(i),
                      "impossible ratio: the pulleys allow joint radii in [" + fmt(p.r_min) + ", " +
                          fmt(p.r_max) + "] m, so R2/R1 must lie within [" + fmt(p.r_min / p.r_max) +
                          ", " + fmt(p.r_max / p.r_min) + "]");
  if (std::abs(i * R1_lo - R1_lo) >= a)
    throw ConfigError("geometry.ratio", fmt(i), "impossible ratio for centre distance " + fmt(a));

  // Closure: the chain has turned by exactly 2 pi when joint N lands on joint 0 (both sit
  // on the regular driving arc). Less turning: the chain is too short for the path.
  int iterations = 0;
  // Where the chain leaves an arc, the articulation that puts a_{i+1} on the path leaves
  // b_i inside it (tens of um). Such joints get their leading half lifted off the path by
  // that deficit, and the walk is repeated until no half starts inside (5.2).
  std::vector<double> lift(N + 1, 0.0);
  auto closure = [&](double R1) {
    BeltPath path(a, R1, i * R1);
    Walk w = walk(path, regular_alpha(path, p, lift[1]), p, N, &lift);
    ++iterations;
    if (!w.ok) return std::nan("");
    return w.psi[N] - w.psi[0] - 2 * M_PI;
  };
  const double f_lo = closure(R1_lo), f_hi = closure(R1_hi * (1 - 1e-9));
  const double length = N * (p.plate_rest - 2 * p.rocker_radius - 2 * p.kappa);
  if (std::isnan(f_lo) || std::isnan(f_hi))
    throw ConfigError("chain.links", std::to_string(N), "the chain cannot be placed on the pulleys");
  if (f_lo < 0)
    throw ConfigError("chain.links", std::to_string(N),
                      "chain too short to wrap the pulleys: length " + fmt(length) +
                          " m does not reach around them even at the smallest admissible radius R1 = " +
                          fmt(R1_lo) + " m");
  if (f_hi > 0)
    throw ConfigError("chain.links", std::to_string(N),
                      "chain too long for the pulleys: length " + fmt(length) +
                          " m is slack even at the largest admissible radius R1 = " + fmt(R1_hi) + " m");

  double R1 = 0;
  Walk w;
  for (int sweep = 0; sweep < 50; ++sweep) {
    R1 = solve_bracketed(closure, R1_lo, R1_hi * (1 - 1e-9), 1e-13, &iterations);
    BeltPath path(a, R1, i * R1);
    w = walk(path, regular_alpha(path, p, lift[1]), p, N, &lift);
    double worst = 0;
    for (int j = 0; j < N; ++j) {
      const double sd = path.sd(w.pb[j]);
      if (sd < -1e-10) {
        lift[j] += -sd;
        worst = std::max(worst, -sd);
      }
    }
    if (worst == 0) break;
  }
  BeltPath path(a, R1, i * R1);

  ChainPlacement out;
  out.rho1 = R1;
  out.rho2 = i * R1;
  out.pa.assign(w.pa.begin(), w.pa.begin() + N);
  out.pb.assign(w.pb.begin(), w.pb.begin() + N);
  // Joint N would be b_N = b_0 after a full turn; the last plate closes the loop.
  out.closure_residual = (w.pb[N] - w.pb[0]).norm();
  out.iterations = iterations;
  out.region.resize(N);
  out.span_dir.resize(N);
  for (int j = 0; j < N; ++j) {
    const Vec2 c = 0.5 * (out.pa[j] + out.pb[j]);
    out.region[j] = path.region(out.pa[j]);
    // A joint counts as wrapped when both halves sit on the circle (within 1 um).
    if (out.region[j] != 2 && std::max(std::abs(path.sd(out.pa[j])), std::abs(path.sd(out.pb[j]))) > 1e-6)
      out.region[j] = 2;
    out.span_dir[j] = path.span_direction(c);
  }
  // Joint-centre radii of the wrapped joints (the pitch radii R1, R2).
  for (int k = 0; k < 2; ++k) {
    double sum = 0;
    int count = 0;
    for (int j = 0; j < N; ++j)
      if (out.region[j] == k) {
        sum += (0.5 * (out.pa[j] + out.pb[j]) - Vec2(k == 0 ? 0.0 : a, 0.0)).norm();
        ++count;
      }
    (k == 0 ? out.R1 : out.R2) = count ? sum / count : (k == 0 ? R1 : i * R1);
  }
  const auto unit_velocity = [&](const Vec2& p) -> Vec2 {
    const int r = path.region(p);
    if (r == 2) return path.span_direction(p);
    const Vec2 rel = p - Vec2(r == 0 ? 0.0 : a, 0.0);
    return Vec2(-rel.y(), rel.x()) / (r == 0 ? out.R1 : out.R2);
  };
  out.unit_va.resize(N);
  out.unit_vb.resize(N);
  for (int j = 0; j < N; ++j) {
    out.unit_va[j] = unit_velocity(out.pa[j]);
    out.unit_vb[j] = unit_velocity(out.pb[j]);
  }
  return out;
}

}  // namespace cvt

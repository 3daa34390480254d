// Modal analysis (docs/model.md 9) against closed forms: RK4's stability boundary on the
// axes, the spectrum of a linear system with chosen eigenvalues, one pin half's beam
// (consistent Hermite element, and the continuous free-free beam and bar), the drive and
// load torsion springs of the mini model, the kinetic-energy split, and an actual RK4
// run on either side of the predicted stable step.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sys/wait.h>
#include <unistd.h>
#include <numbers>
#include <random>

#include <Eigen/Eigenvalues>
#include <nlohmann/json.hpp>

#include "engine/studies/modes.hpp"
#include "engine/rhs/rhs.hpp"
#include "engine/simulation.hpp"
#include "modules/beam.hpp"
#include "modules/chain_forces.hpp"
#include "modules/inertia.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

constexpr double kPi = std::numbers::pi;

// The real root of z^3 + 4 z^2 + 12 z + 24 = 0, i.e. R(z) = 1 with z != 0 on the real
// axis (R(z) - 1 = z (1 + z/2 + z^2/6 + z^3/24)), by Cardano; -2.785293563405...
double rk4_real_axis_root() {
  // Depressed cubic for z = u - 4/3: u^3 + p u + q = 0.
  const double a = 4, b = 12, c = 24;
  const double p = b - a * a / 3, q = 2 * a * a * a / 27 - a * b / 3 + c;
  const double d = std::sqrt(q * q / 4 + p * p * p / 27);
  return std::cbrt(-q / 2 + d) + std::cbrt(-q / 2 - d) - a / 3;
}

TEST(ModesRk4, RayBoundOnTheAxes) {
  const double real_root = rk4_real_axis_root();
  EXPECT_NEAR(real_root, -2.785293563405, 1e-11);  // the textbook value, to its printed digits
  EXPECT_NEAR(rk4_ray_bound(kPi), -real_root, 1e-12);
  // |R(iy)|^2 = 1 - y^6/72 + y^8/576: 1 again at y^2 = 8.
  EXPECT_NEAR(rk4_ray_bound(kPi / 2), 2 * std::sqrt(2.0), 1e-12);
  EXPECT_NEAR(rk4_ray_bound(-kPi / 2), 2 * std::sqrt(2.0), 1e-12);
  // Into the right half plane nothing is stable.
  EXPECT_EQ(rk4_ray_bound(0.0), 0.0);
  EXPECT_EQ(rk4_ray_bound(kPi / 3), 0.0);
  // Any direction in between: on the boundary |R| = 1, just inside below, just outside above.
  for (double theta : {0.55 * kPi, 0.6 * kPi, 0.75 * kPi, 0.9 * kPi}) {
    const double r = rk4_ray_bound(theta);
    const auto dir = std::polar(1.0, theta);
    EXPECT_NEAR(std::abs(rk4_amplification(r * dir)), 1.0, 1e-10) << theta;
    EXPECT_LT(std::abs(rk4_amplification(0.999 * r * dir)), 1.0) << theta;
    EXPECT_GT(std::abs(rk4_amplification(1.001 * r * dir)), 1.0) << theta;
    EXPECT_GT(r, 2.0) << theta;
    EXPECT_LT(r, 3.0) << theta;
  }
  EXPECT_NEAR(rk4_stable_step({-1e8, 0}), 2.785293563405e-8, 1e-19);
  EXPECT_TRUE(std::isinf(rk4_stable_step({0, 0})));
}

// J = S D S^-1 with D the real block form of chosen eigenvalues; the analysis sees J only
// through central differences of y -> J y.
Eigen::MatrixXd matrix_with_eigenvalues(const std::vector<std::complex<double>>& eig, unsigned seed) {
  const int n = static_cast<int>(eig.size());
  Eigen::MatrixXd D = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) {
    if (eig[i].imag() == 0) {
      D(i, i) = eig[i].real();
    } else {  // a conjugate pair occupies two slots
      D(i, i) = D(i + 1, i + 1) = eig[i].real();
      D(i, i + 1) = eig[i].imag();
      D(i + 1, i) = -eig[i].imag();
      ++i;
    }
  }
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::MatrixXd S(n, n);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) S(i, j) = (i == j ? 2.0 : 0.0) + 0.3 * u(rng);
  return S * D * S.inverse();
}

Rk4Stability analyse_linear(const Eigen::MatrixXd& M) {
  const Eigen::VectorXd y = Eigen::VectorXd::Constant(M.rows(), 0.1);
  const Eigen::MatrixXd J = jacobian_by_differences([&](const Eigen::VectorXd& x, Eigen::VectorXd& f) { f = M * x; },
                                                    y, Eigen::VectorXd::Constant(M.rows(), 1e-6));
  Eigen::EigenSolver<Eigen::MatrixXd> es(J, false);
  const double rho = es.eigenvalues().cwiseAbs().maxCoeff();
  return rk4_stability(es.eigenvalues(), 1e-7 * rho);
}

TEST(ModesRk4, SpectrumOfALinearSystem) {
  using c = std::complex<double>;
  // The real eigenvalue has the largest modulus and sets the step: 2.7853 / 3e6.
  {
    const auto s = analyse_linear(matrix_with_eigenvalues(
        {c(-3e6, 0), c(0, 2.5e6), c(0, -2.5e6), c(-1e5, 1e5), c(-1e5, -1e5), c(-10, 0), c(0, 0), c(5, 0)}, 1));
    EXPECT_NEAR(s.rho, 3e6, 3e6 * 1e-7);
    EXPECT_NEAR(s.lambda_rho.real(), -3e6, 3e6 * 1e-7);
    EXPECT_NEAR(s.h_stable, 2.785293563405 / 3e6, 1e-9 * 2.785 / 3e6 + 1e-18);
    EXPECT_NEAR(s.h_rho, s.h_stable, 1e-18);
    EXPECT_EQ(s.zero, 1);     // the 0
    EXPECT_EQ(s.growing, 1);  // the +5
    EXPECT_NEAR(s.max_growth, 5.0, 1e-3);
  }
  // Now the imaginary pair sets the step (2 sqrt 2 / 2e6 < 2.7853 / 1e6), while the
  // largest modulus belongs to it too; a decaying pair of larger modulus in a direction
  // with a longer ray would not.
  {
    const auto s = analyse_linear(matrix_with_eigenvalues({c(-1e6, 0), c(0, 2e6), c(0, -2e6), c(-5, 0)}, 2));
    EXPECT_NEAR(s.rho, 2e6, 2e6 * 1e-7);
    EXPECT_NEAR(s.h_stable, 2 * std::sqrt(2.0) / 2e6, 1e-7 * 1.4142e-6);
    EXPECT_NEAR(std::abs(s.lambda_limit.imag()), 2e6, 2e6 * 1e-7);
  }
}

// One pin half: the stiffness from the beam kernel itself (central differences of the
// generalized forces at the straight rest shape), the mass from the model's A0 blocks.
struct HalfSpectrum {
  std::vector<double> omega2;  // ascending
};

HalfSpectrum half_spectrum(const Model& m) {
  const double L = m.L0;
  Eigen::VectorXd q = Eigen::VectorXd::Zero(half::kSize);
  q[half::kZ] = -L / 2;
  q[half::kEnd + half::kZ] = L / 2;
  const double v[half::kSize] = {};
  const Eigen::MatrixXd dF = jacobian_by_differences(
      [&](const Eigen::VectorXd& x, Eigen::VectorXd& f) {
        f = Eigen::VectorXd::Zero(half::kSize);
        beam(m, x.data(), v, f.data());
      },
      q, Eigen::VectorXd::Constant(half::kSize, 1e-7));
  const Eigen::MatrixXd K = -0.5 * (dF + dF.transpose());
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(half::kSize, half::kSize);
  for (int pl = 0; pl < 2; ++pl) {
    const auto d = plane_dofs(pl);
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) A(d[i], d[j]) = m.bend_mass(i, j);
  }
  const int z[2] = {half::kZ, half::kEnd + half::kZ};
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j) A(z[i], z[j]) = m.axial_mass(i, j);
  const GeneralizedModes g = generalized_modes(K, A);
  HalfSpectrum s;
  for (int i = 0; i < g.omega2.size(); ++i) s.omega2.push_back(g.omega2[i]);
  return s;
}

// Closed forms of the free-free Hermite element with consistent mass m and the plate mass
// mu lumped on each end's translation (derivation in docs/model.md 9.5): symmetric bending
// w^2 = 4k (m + 2mu) / ((m + 2mu) m/30 - m^2/36), antisymmetric 12k (m/3 + 2mu) /
// (m^2/2100 + mu m/105), k = EI/L^3; axial (bar, no lumps) 12 EA/(m L).
struct Closed {
  double sym, anti, axial;
};
Closed closed_form(double EI, double EA, double L, double m, double mu) {
  const double k = EI / (L * L * L);
  return {4 * k * (m + 2 * mu) / ((m + 2 * mu) * m / 30 - m * m / 36),
          12 * k * (m / 3 + 2 * mu) / (m * m / 2100 + mu * m / 105), 12 * EA / (m * L)};
}

void expect_half_spectrum(const Model& m, double mu) {
  const HalfSpectrum s = half_spectrum(m);
  const auto& p = m.cfg.pin;
  const Closed c = closed_form(p.ei, p.ea, m.L0, p.mass, mu);
  ASSERT_EQ(s.omega2.size(), 10u);
  const double top = s.omega2.back();
  // Five rigid motions: axial translation, two translations and two rotations.
  for (int i = 0; i < 5; ++i) EXPECT_LT(std::abs(s.omega2[i]), 1e-8 * top) << i;
  std::vector<double> expect = {c.sym, c.sym, c.anti, c.anti, c.axial};
  std::sort(expect.begin(), expect.end());
  for (int i = 0; i < 5; ++i) EXPECT_NEAR(s.omega2[5 + i], expect[i], 1e-6 * expect[i]) << i;
}

TEST(ModesSinglePinHalf, ConsistentElementClosedForm) {
  // With the model's plate lumps (4 plates of 1.6 g: mu = n_pl m_pl / 4 = 1.6 g per end).
  const Model m = test::model("mini");
  const double mu = m.cfg.chain.plates_per_link * m.cfg.chain.plate_mass / 4;
  EXPECT_NEAR(m.bend_mass(0, 0) - 156.0 / 420 * m.cfg.pin.mass, mu, 1e-15);
  expect_half_spectrum(m, mu);
}

TEST(ModesSinglePinHalf, BareElementAgainstContinuousBeam) {
  // Plates made negligible: the textbook free-free element, w^2 = 720 and 8400 EI/(m L^3)
  // in bending and 12 EA/(m L) in tension; the continuous free-free beam has
  // (beta L)^4 = 500.564 and 3803.54, the bar pi^2 EA/(m L). One element overestimates
  // (Rayleigh-Ritz: never below), by 20 %, 49 % and 10 % in w.
  const Model m = test::model("mini", {"chain.plate_mass=1e-12"});
  const auto& p = m.cfg.pin;
  const double L = m.L0, k = p.ei / (L * L * L * p.mass), a = p.ea / (p.mass * L);
  const HalfSpectrum s = half_spectrum(m);
  std::vector<double> flex(s.omega2.begin() + 5, s.omega2.end());
  // Which is which by size (mini/reference: 720 k < 8400 k < 12 a).
  ASSERT_LT(8400 * k, 12 * a);
  EXPECT_NEAR(flex[0] / k, 720, 720 * 1e-6);
  EXPECT_NEAR(flex[1] / k, 720, 720 * 1e-6);
  EXPECT_NEAR(flex[2] / k, 8400, 8400 * 1e-6);
  EXPECT_NEAR(flex[3] / k, 8400, 8400 * 1e-6);
  EXPECT_NEAR(flex[4] / a, 12, 12 * 1e-6);
  const double beam1 = std::pow(4.730040745, 4), beam2 = std::pow(7.853204624, 4), bar1 = kPi * kPi;
  const double r1 = std::sqrt(flex[0] / k / beam1), r2 = std::sqrt(flex[2] / k / beam2),
               ra = std::sqrt(flex[4] / a / bar1);
  EXPECT_GT(r1, 1.0);
  EXPECT_LT(r1, 1.21);
  EXPECT_GT(r2, 1.0);
  EXPECT_LT(r2, 1.50);
  EXPECT_GT(ra, 1.0);
  EXPECT_LT(ra, 1.11);
}

// The mini model at t = 0 (no clamping yet, contacts unloaded): the driving pulley's
// rotation sees only the drive's torsion spring, w^2 = k_t / J_p; the driven pulley and
// the load form a two-inertia torsion pair, w^2 = k_l (1/J_p + 1/J_L), plus a free
// rotation of both.
TEST(ModesTorsion, DriveAndLoadSprings) {
  const Model m = test::model("mini");
  Simulation sim(m);
  const Linearization L = linearize(m, sim.workspace().status, 0.0, sim.state(), false);
  const GeneralizedModes g = generalized_modes(0.5 * (L.K + L.K.transpose()), L.A);
  const double Jp = m.cfg.shaft.polar_inertia, JL = m.cfg.load.inertia;
  const double drive = m.cfg.drive.stiffness / Jp, load = m.cfg.load.stiffness * (1 / Jp + 1 / JL);
  auto nearest = [&](double w2) {
    int best = 0;
    for (int i = 0; i < g.omega2.size(); ++i)
      if (std::abs(g.omega2[i] - w2) < std::abs(g.omega2[best] - w2)) best = i;
    return best;
  };
  const int id = nearest(drive), il = nearest(load);
  EXPECT_NEAR(g.omega2[id], drive, 1e-6 * drive);
  EXPECT_NEAR(g.omega2[il], load, 1e-6 * load);
  const EnergyParts ed = energy_parts(m, sim.state().data(), g.vectors.col(id));
  EXPECT_GT(ed.shaft[0][3] / ed.total(), 0.999);
  const auto pd = dominant_parts(m, ed, 1);
  ASSERT_EQ(pd.size(), 1u);
  EXPECT_EQ(pd[0].name, "driving shaft rotation");
  const EnergyParts el = energy_parts(m, sim.state().data(), g.vectors.col(il));
  // Relative motion: kinetic energies in the ratio J_L : J_p of the inertias' inverses.
  EXPECT_NEAR((el.shaft[1][3] + el.load) / el.total(), 1.0, 1e-3);
  EXPECT_NEAR(el.shaft[1][3] / el.load, JL / Jp, 1e-3 * JL / Jp);
  // Driven pulley and load turning together by the same angle is a free motion: K x = 0.
  // (At t = 0 many chain mechanisms sit near w = 0 too and mix with it in the computed
  // null space, so this checks K rather than one eigenvector.)
  const Eigen::MatrixXd Ks = 0.5 * (L.K + L.K.transpose());
  Eigen::VectorXd x = Eigen::VectorXd::Zero(m.ndof);
  x[m.shaft(1) + kPhi] = x[m.load_index()] = 1.0;
  EXPECT_LT((Ks * x).norm(), 1e-8 * m.cfg.load.stiffness);  // differences: rounding ~ 4e-9
  // The relative motion is not free.
  x[m.load_index()] = -1.0;
  EXPECT_NEAR((Ks * x).norm(), 2 * std::sqrt(2.0) * m.cfg.load.stiffness, 1e-6 * m.cfg.load.stiffness);
}

TEST(ModesEnergyParts, SumToTheKineticEnergyAndNameThePart) {
  const Model m = test::model("mini");
  const Eigen::VectorXd y = test::perturbed_state(m, 7, 1e-5, 1e-3, 1.0);
  const Eigen::MatrixXd A = dense_inertia(m, y.data());
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::VectorXd x(m.ndof);
  for (int i = 0; i < m.ndof; ++i) x[i] = u(rng);
  const EnergyParts e = energy_parts(m, y.data(), x);
  const double xAx = x.dot(A * x);
  EXPECT_NEAR(e.total(), xAx, 1e-12 * xAx);
  // One coordinate alone: the part it belongs to, 100 %.
  Eigen::VectorXd one = Eigen::VectorXd::Zero(m.ndof);
  one[m.half_b(5) + half::kZ] = 1.0;
  auto p = dominant_parts(m, energy_parts(m, y.data(), one), 1);
  ASSERT_EQ(p.size(), 1u);
  EXPECT_EQ(p[0].name, "pin 5 half b axial");
  EXPECT_NEAR(p[0].share, 1.0, 1e-12);
  // A pure bending shape of half a_3 in x (the first flexible mode's symmetric form).
  one.setZero();
  const int a3 = m.half_a(3);
  one[a3 + half::kSx] = 1.0;
  one[a3 + half::kEnd + half::kSx] = -1.0;
  one[a3 + half::kX] = one[a3 + half::kEnd + half::kX] = -m.L0 / 6;
  p = dominant_parts(m, energy_parts(m, y.data(), one), 1);
  ASSERT_EQ(p.size(), 1u);
  EXPECT_EQ(p[0].name.find("pin 3 half a"), 0u) << p[0].name;
}

// The predicted stable step against RK4 itself on the mini model, clamped and running
// (ramp shortened to 0.1 ms, state at 0.2 ms): a velocity perturbation of 1e-9 m/s,
// carried by RK4 over 40 steps beside the unperturbed run (statuses frozen in both), stays
// within the transient growth of a stable step below h* and grows by orders of magnitude
// above it. Its size stays far below friction.v0, so the friction law is still linear
// there (a finite disturbance would saturate at |v_t| ~ v0 instead of blowing up: the
// nonsmooth law's slope drops to 0 beyond v0).
TEST(ModesRk4, PredictedStepAgainstARunOnMini) {
  const Model m = test::model("mini", {"ramp.time=1e-4"});
  Simulation sim(m);
  const double h0 = m.cfg.integrator.step;
  for (int s = 0; s < 20000; ++s) sim.step(h0);
  ModesOptions opt;
  opt.count = 1;
  const ModalReport r = modal_analysis(m, sim.workspace().status, sim.time(), sim.state(), opt);
  const double h = r.stability.h_stable;
  ASSERT_TRUE(std::isfinite(h) && h > 0);
  std::printf("mini at t = %g s: rho = %.4g 1/s, lambda_limit = %.4g%+.4gi, h* = %.4g s\n", sim.time(),
              r.stability.rho, r.stability.lambda_limit.real(), r.stability.lambda_limit.imag(), h);
  const Checkpoint c = sim.checkpoint();
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::VectorXd dlt = Eigen::VectorXd::Zero(m.nstate);
  for (int i = m.ndof; i < 2 * m.ndof; ++i) dlt[i] = 1e-9 * u(rng);
  auto growth = [&](double step) {
    Simulation a(m), b(m);
    a.restore(c);
    b.restore(c);
    b.mutable_state() += dlt;
    for (int k = 0; k < 40; ++k) {
      a.step(step, false);
      b.step(step, false);
    }
    return (b.state() - a.state()).segment(m.ndof, m.ndof).norm() / dlt.norm();
  };
  const double below = growth(0.95 * h), above = growth(1.1 * h);
  std::printf("perturbation growth over 40 steps: %.3g at 0.95 h*, %.3g at 1.1 h*\n", below, above);
  EXPECT_LT(below, 1e3);
  EXPECT_GT(above, 1e5);
}

// The command line: exit codes of docs/cli.md and the JSON report.
int run_engine(const std::string& args, const std::string& out_file) {
  const std::string cmd =
      test::shell_quote(CVT_ENGINE_EXE) + " " + args + " >" + test::shell_quote(out_file) + " 2>&1";
  const int status = std::system(cmd.c_str());
  return status != -1 && WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

std::string slurp(const std::string& path) {
  std::ifstream f(path);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

// The report's JSON parses whatever its names hold; shares carry the six digits the report
// gives them, frequencies every digit, and a non-finite figure is null.
TEST(ModesJson, ParsesWithAnyNamesAndNonFiniteFigures) {
  ModalReport r;
  ModeRow row;
  row.index = 4;
  row.omega2 = std::nan("");
  row.freq_hz = 1.0 / 3.0;
  row.parts = {{"pin \"a\" \\ \n\x02 \u00e9", 0.123456789}};
  r.lowest = {row};
  r.has_jacobian = true;
  r.stability.rho = HUGE_VAL;
  const nlohmann::json j = nlohmann::json::parse(modal_report_json(r, 1e-7));
  const auto& got = j.at("lowest").at(0);
  EXPECT_TRUE(got.at("omega2").is_null());
  EXPECT_EQ(got.at("frequency_hz").get<double>(), row.freq_hz);
  EXPECT_EQ(got.at("parts").at(0).at("name").get<std::string>(), row.parts[0].name);
  EXPECT_EQ(got.at("parts").at(0).at("share").get<double>(), 0.123457);
  EXPECT_TRUE(j.at("jacobian").at("rho").is_null());
  EXPECT_EQ(j.at("jacobian").at("config_step").get<double>(), 1e-7);
}

TEST(ModesCli, ExitCodesAndJson) {
  const auto dir = std::filesystem::temp_directory_path() / ("cvt_modes_cli_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string out = (dir / "out.txt").string(), json = (dir / "modes.json").string();
  const std::string mini = test::shell_quote(test::config_path("mini"));
  EXPECT_EQ(run_engine("modes " + mini + " --count 0", out), 64) << slurp(out);
  EXPECT_EQ(run_engine("modes " + mini + " --at -1", out), 64) << slurp(out);
  EXPECT_EQ(run_engine("modes " + mini + " --bogus", out), 64) << slurp(out);
  EXPECT_EQ(run_engine("modes " + mini + " --set chain.links=5", out), 78) << slurp(out);
  EXPECT_EQ(run_engine("modes " + mini + " --no-jacobian --count 3 --json " + test::shell_quote(json), out), 0)
      << slurp(out);
  const std::string text = slurp(out), js = slurp(json);
  EXPECT_NE(text.find("natural frequencies"), std::string::npos) << text;
  EXPECT_NE(text.find("lowest:"), std::string::npos) << text;
  const nlohmann::json j = nlohmann::json::parse(js);
  ASSERT_EQ(j.at("highest").size(), 3u) << js;
  for (const auto& row : j.at("highest")) EXPECT_TRUE(row.at("frequency_hz").is_number()) << js;
  EXPECT_FALSE(j.contains("jacobian")) << js;
  EXPECT_EQ(run_engine("modes " + mini + " --no-jacobian --json /nonexistent-dir/x.json", out), 1) << slurp(out);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace cvt

// Initial chain geometry (docs/model.md 5): the chain as a kinematic chain of links,
// placed on the belt path of two pitch circles with straight spans so that every rocker
// pair just touches and every plate sits at its rest length.
#pragma once

#include <Eigen/Dense>
#include <vector>

namespace cvt {

struct ChainPathParams {
  double centre_distance, ratio;  // a, R2/R1
  int links;
  double plate_rest;    // l0 = p + d_h
  double kappa;         // d_h/2 - R_r
  double rocker_radius; // R_r
  double r_min, r_max;  // admissible joint radii on the pulleys
};

struct ChainPlacement {
  double R1 = 0, R2 = 0;                  // joint-centre radii on the two arcs
  double rho1 = 0, rho2 = 0;              // radii of the half centre lines on the arcs (the path)
  std::vector<Eigen::Vector2d> pa, pb;    // half centre lines (xy) of every joint
  std::vector<int> region;                // 0: arc of pulley 0, 1: arc of pulley 1, 2: span
  std::vector<Eigen::Vector2d> span_dir;  // travel direction (spans only)
  // Initial velocity of each half per unit chain speed (docs/model.md 5.4): rigid rotation
  // with its pulley where the half lies in that pulley's sector of the path, the span
  // direction elsewhere. Classified half by half, so the field is continuous along the path.
  std::vector<Eigen::Vector2d> unit_va, unit_vb;
  double closure_residual = 0;            // |c_N - c_0| after the walk [m]
  int iterations = 0;
};

struct Config;

// The path parameters of a configuration at its geometry.ratio: the joints' admissible
// radii r_hub + p/2 .. r_out - p/2 (docs/model.md 5.1).
ChainPathParams chain_path_params(const Config& cfg);

// Places the chain; throws ConfigError when the chain cannot wrap the pulleys.
ChainPlacement place_chain(const ChainPathParams& p);

// Whether place_chain places the chain at p.ratio (the same tests, without placing it).
bool chain_fits(const ChainPathParams& p);

}  // namespace cvt

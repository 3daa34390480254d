// cvt-engine study slip (docs/studies.md): for each clamping force (and ratio), the
// largest load torque the chain holds without gross slip, found by bisection over
// load.torque with runs until steady, beside the Coulomb capacity of the weaker pulley in
// output torque, 2 f0 min(F1, F2) R2 / cos(beta).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "engine/studies/sweep.hpp"

namespace cvt {

struct SlipStudyOptions {
  SweepOptions sweep;                   // config, --set, schedule; runs in OUT.runs/
  std::vector<double> clamping;         // clamping.driving values [N]
  double thrust_ratio = 0;              // F1 / F2 for every point; 0: the configuration's
  std::vector<std::string> ratios;      // geometry.ratio values; empty: the configuration's
  double tolerance = 0.02;              // bisection until (upper - lower) / lower <= this
  std::string csv;                      // the rows, one per clamping force and ratio
};

struct SlipRow {
  double clamping_driving = 0, clamping_driven = 0, ratio = 0;
  double theory_torque = 0;  // 2 f0 min(F1, F2) R2 / cos(beta) [N m]
  double slip_torque = 0;    // the largest load torque that held (no gross slip) [N m]
  double slips_at = 0;       // the smallest that slipped [N m]
  int runs = 0;
  double wall_s = 0;
  std::string note;          // e.g. a blow-up taken as a slip
};

// The Coulomb capacity of the weaker pulley in output torque for this configuration.
double slip_theory_torque(const std::string& config_path, const std::vector<std::string>& overrides);

std::vector<SlipRow> run_slip_study(const SlipStudyOptions& o);
std::string slip_csv_header();
std::string slip_csv_row(const SlipRow& r);

}  // namespace cvt

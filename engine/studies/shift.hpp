// cvt-engine study shift (docs/studies.md): how fast the ratio shifts after a step in the
// thrust ratio F1/F2. At each input speed the configuration is run until steady; from
// that state (its checkpoint) each thrust ratio is applied as a step in F1 (F2 kept) and
// the geometric ratio's rate of change d(ratio)/dt is fitted over the shift window.
// Published trend (Carbone, Mangialardi, Bonsen et al., Mech. Mach. Theory 42, 2007): the
// rate grows linearly with ln(F1/F2) and in proportion to the primary speed.
#pragma once

#include <string>
#include <vector>

#include "engine/studies/sweep.hpp"

namespace cvt {

struct ShiftStudyOptions {
  SweepOptions sweep;                  // config, --set, schedule, log
  std::vector<double> thrust_ratios;   // F1/F2 after the step
  std::vector<double> speeds;          // drive.speed values [rad/s]; empty: the configuration's
  double settle = 2e-3;                // after the step, left out of the fit [s]
  double window = 1e-2;                // the fit's window after that [s]
  double steady_bound = 0.3;           // t_end of the runs to the steady state [s]
  std::string csv;
};

struct ShiftRow {
  double input_speed = 0, thrust_ratio = 0, ln_thrust_ratio = 0;
  double steady_thrust_ratio = 0;      // F1/F2 of the steady state the step starts from
  double shift_rate = 0;               // d(geometric ratio)/dt, least squares over the window [1/s]
  double ratio_start = 0, ratio_end = 0;
  std::string steady_status;           // the starting state's status
  double wall_s = 0;
};

std::vector<ShiftRow> run_shift_study(const ShiftStudyOptions& o);
std::string shift_csv_header();
std::string shift_csv_row(const ShiftRow& r);

// The least-squares slope of y over t for t in [t0, t1] (0 with fewer than 2 samples).
double fitted_slope(const std::vector<double>& t, const std::vector<double>& y, double t0, double t1);

}  // namespace cvt

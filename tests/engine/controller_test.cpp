// The ratio controller with the slip-safe clamping (docs/model.md 4.6.4, docs/studies.md
// "The ratio controller"): it shifts along its target profile, the chain carries the load
// without gross slip, and neither clamping force drops below the slip-safe force. On the
// mini model and, as a Slow test, the reference model's 1.0 -> 1.2 -> 0.8 under its load.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>

#include "engine/io/h5_writer.hpp"
#include "engine/rhs/rhs.hpp"
#include "engine/run.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

struct Channels {
  std::vector<double> t, geometric, slip, output_torque, load_torque, f1, f2;
};

// Runs CONFIG with the overrides and reads the channels back from its file.
Channels run_and_read(const std::string& config, const std::vector<std::string>& ov, const std::string& name, Model* model) {
  *model = build_model(load_config(test::config_path(config), ov));
  const RunOptions o = test::quiet_run_options(name);
  const RunResult r = run_simulation(*model, o);
  EXPECT_NE(r.status, "blow_up");
  H5File f = H5File::open(o.out_path);
  auto value = [&](const char* ch) { return f.read_doubles(std::string("/observables/") + ch + "/value"); };
  Channels c;
  c.t = f.read_doubles("/observables/geometric_ratio/time");
  c.geometric = value("geometric_ratio");
  c.slip = value("slip");
  c.output_torque = value("output_torque");
  c.load_torque = value("load_torque");
  c.f1 = value("clamping_force_driving");
  c.f2 = value("clamping_force_driven");
  f.close();
  test::remove_run_files(o.out_path);
  return c;
}

// The mean of a channel over [a, b).
double mean(const Channels& c, const std::vector<double>& x, double a, double b) {
  double s = 0;
  long n = 0;
  for (std::size_t i = 0; i < c.t.size(); ++i)
    if (c.t[i] >= a && c.t[i] < b) s += x[i], ++n;
  return n ? s / n : NAN;
}

// Over every window of length w from t0 on: the mean slip stays below 5 % (no gross slip),
// the mean output torque carries at least `carried` of the mean load torque, and the
// smaller clamping force is at least the slip-safe force of the load alone,
// S M_load cos(beta) / (2 f0 R2) with R2 at most the outer radius.
void expect_carried_without_slip(const Model& m, const Channels& c, double t0, double w, double carried) {
  const Config& k = m.cfg;
  const double least = k.controller.clamping_safety * k.load.torque * m.cos_beta / (2 * k.friction.f0 * k.sheave.outer_radius);
  for (double a = t0; a + w <= c.t.back() + 1e-12; a += w) {
    const double slip = mean(c, c.slip, a, a + w), mo = mean(c, c.output_torque, a, a + w),
                 ml = mean(c, c.load_torque, a, a + w);
    const double fmin = std::min(mean(c, c.f1, a, a + w), mean(c, c.f2, a, a + w));
    std::printf("  t %.3f-%.3f s: geometric ratio %.4f, slip %+.2f %%, output %.1f / load %.1f N m, F1 %.2f F2 %.2f kN\n", a,
                a + w, mean(c, c.geometric, a, a + w), 100 * slip, mo, ml, mean(c, c.f1, a, a + w) / 1e3,
                mean(c, c.f2, a, a + w) / 1e3);
    EXPECT_LT(std::abs(slip), 0.05) << "gross slip in the window from " << a << " s";
    EXPECT_GT(mo, carried * ml) << "the output torque drops in the window from " << a << " s";
    EXPECT_GT(fmin, least) << "a clamping force below the slip-safe force from " << a << " s";
  }
}

// The mini model, its load 10 N m, the configured forces low (3 kN) so that the torque sets
// them: asked to go from 1.0 to 1.15 over 25 ms, the sheaves' ratio follows and holds it.
TEST(ControllerTest, MiniShiftsToItsTargetWithSlipSafeForces) {
  Model m;
  const Channels c = run_and_read("mini",
                                  {"controller.enabled=true", "controller.clamping_safety=3", "controller.shift_kp=20",
                                   "controller.shift_ki=400", "clamping.driving=3e3", "clamping.driven=3e3",
                                   "controller.target_profile=[[0.005, 1.0], [0.03, 1.15]]", "run.t_end=0.05"},
                                  "controller_mini", &m);
  expect_carried_without_slip(m, c, 0.005, 0.005, 0.7);
  EXPECT_NEAR(mean(c, c.geometric, 0.045, 0.05), 1.15, 0.02 * 1.15) << "the ratio must reach its target";
  EXPECT_LT(mean(c, c.geometric, 0.0, 0.005), 1.01) << "the ratio must start from the chain's own";
}

// configs/reference-shift.toml: the reference model under its 150 N m load, from rest,
// holds 1.0, shifts to 1.2, holds, shifts to 0.8, holds. The ratio reaches each target
// (within 3 %: the PI overshoots the end of each ramp by about 2 %), the chain never slips
// grossly, and the output torque is carried throughout (on the way down it also
// accelerates the load; on the way up the decelerating load gives some back).
TEST(ControllerTest, SlowReferenceShiftsUnderLoadWithoutSlip) {
  Model m;
  const Channels c = run_and_read("reference-shift", {}, "controller_reference", &m);
  ASSERT_NEAR(c.t.back(), 0.55, 1e-9) << "the run must reach the profile's end";
  expect_carried_without_slip(m, c, 0.04, 0.02, 0.8);
  EXPECT_NEAR(mean(c, c.geometric, 0.04, 0.06), 1.0, 0.01) << "the ratio must hold 1.0";
  EXPECT_NEAR(mean(c, c.geometric, 0.22, 0.24), 1.2, 0.03 * 1.2) << "the ratio must reach 1.2";
  EXPECT_NEAR(mean(c, c.geometric, 0.53, 0.55), 0.8, 0.03 * 0.8) << "the ratio must reach 0.8";
}

// The shift gains act at controller.gain_speed: the same ratio error and integral give the
// same clamping forces at twice the input speed with twice the gains, and other forces at
// the speed they are given for; gain_speed = 0 leaves them unscaled.
TEST(ControllerTest, ShiftGainsAreScaledByTheInputSpeed) {
  const auto clamp = [](double speed, double kp, double ki, double gain_speed) {
    char b[4][64];
    std::snprintf(b[0], sizeof b[0], "drive.speed=%.17g", speed);
    std::snprintf(b[1], sizeof b[1], "controller.shift_kp=%.17g", kp);
    std::snprintf(b[2], sizeof b[2], "controller.shift_ki=%.17g", ki);
    std::snprintf(b[3], sizeof b[3], "controller.gain_speed=%.17g", gain_speed);
    const Model m = build_model(load_config(test::config_path("mini"),
                                            {"controller.enabled=true", "controller.clamping_safety=3",
                                             "controller.target_ratio=1.01", b[0], b[1], b[2], b[3]}));
    Workspace ws(m);
    Eigen::VectorXd y = m.y0, dy(m.nstate);
    y[2 * m.ndof + kCtrlIntegral] = 1e-4;  // an integral of the ratio error (below the thrust limit)
    rhs_serial(m, ws, 5e-3, y.data(), dy.data());
    return std::array<double, 2>{ws.other.clamp[0], ws.other.clamp[1]};
  };
  const auto base = clamp(209.4, 20, 400, 209.4), doubled = clamp(418.8, 40, 800, 209.4);
  const auto plain = clamp(418.8, 20, 400, 209.4), unscaled = clamp(418.8, 20, 400, 0);
  for (int k = 0; k < 2; ++k) EXPECT_NEAR(doubled[k], base[k], 1e-9 * base[k]) << k;
  EXPECT_NE(base, plain) << "the error does not reach the forces: the case tests nothing";
  EXPECT_NE(plain, unscaled);
  const auto at_gain_speed = clamp(418.8, 20, 400, 418.8);
  for (int k = 0; k < 2; ++k) EXPECT_EQ(at_gain_speed[k], unscaled[k]) << k;
}

// The slip-safe clamping rebuilds a W-method's stiffness at least every 16 steps: a longer
// interval is lowered to 16 (a multiple of w_every), a shorter one kept, and without the
// controller nothing changes; the resolved configuration says what the run used.
TEST(ControllerTest, TheSlipSafeClampingRebuildsTheStiffnessEvery16StepsAtMost) {
  const auto every = [](std::vector<std::string> ov) {
    return load_config(test::config_path("mini"), ov).integrator.w_k_every;
  };
  const std::vector<std::string> on = {"controller.enabled=true", "controller.clamping_safety=3"};
  auto with = [&](std::string k) {
    auto v = on;
    v.push_back(std::move(k));
    return v;
  };
  EXPECT_EQ(every(with("integrator.w_k_every=64")), 16);
  EXPECT_EQ(every(with("integrator.w_k_every=8")), 8);
  EXPECT_EQ(every({"integrator.w_k_every=64"}), 64);
  auto ov = with("integrator.w_k_every=60");
  ov.push_back("integrator.w_every=6");
  EXPECT_EQ(every(ov), 12);
  const Config c = load_config(test::config_path("mini"), with("integrator.w_k_every=64"));
  EXPECT_NE(c.resolved_toml.find("w_k_every = 16"), std::string::npos);
}

}  // namespace
}  // namespace cvt

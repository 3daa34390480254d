// Tests of engine/config: loading, validation, overrides and the resolved TOML.
#include "engine/model/config.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

namespace cvt {
namespace {

const std::string kConfigDir = std::string(CVT_SOURCE_DIR) + "/configs/";

// Expects `fn` to throw a ConfigError naming `key` whose message contains `value`.
// Returns the error so that a test can check more.
ConfigError expect_error(const std::function<void()>& fn, const std::string& key, const std::string& value) {
  try {
    fn();
  } catch (const ConfigError& e) {
    EXPECT_EQ(e.key(), key) << e.what();
    EXPECT_NE(std::string(e.what()).find(value), std::string::npos)
        << "message does not contain '" << value << "': " << e.what();
    return e;
  }
  ADD_FAILURE() << "no ConfigError for key " << key;
  return ConfigError("", "", "");
}

ConfigError expect_parse_error(const std::string& text, const std::string& key, const std::string& value) {
  return expect_error([&] { parse_config(text); }, key, value);
}

ConfigError expect_override_error(const std::string& set, const std::string& key, const std::string& value) {
  return expect_error([&] { parse_config("", {set}); }, key, value);
}

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

// Every field, compared one by one (bitwise for doubles).
void expect_same(const Config& a, const Config& b) {
#define SAME(field) EXPECT_EQ(a.field, b.field) << #field
  SAME(geometry.centre_distance); SAME(geometry.ratio);
  SAME(chain.links); SAME(chain.pitch); SAME(chain.plates_per_link); SAME(chain.plate_mass);
  SAME(chain.plate_stiffness); SAME(chain.plate_damping); SAME(chain.plate_spread);
  SAME(chain.link_inertia); SAME(chain.pack_stiffness); SAME(chain.pack_damping);
  SAME(pin.length); SAME(pin.ea); SAME(pin.ei); SAME(pin.mass); SAME(pin.damping_time); SAME(pin.tilt_stiffness);
  SAME(rocker.stations); SAME(rocker.radius); SAME(rocker.half_distance); SAME(rocker.stiffness);
  SAME(rocker.damping);
  SAME(pulley_contact.end_radius); SAME(pulley_contact.stiffness); SAME(pulley_contact.damping);
  SAME(friction.law); SAME(friction.f0); SAME(friction.v0);
  SAME(sheave.cone_angle); SAME(sheave.outer_radius); SAME(sheave.hub_radius);
  SAME(shaft.mass); SAME(shaft.polar_inertia); SAME(shaft.tilt_inertia); SAME(shaft.sheave_mass);
  SAME(bearing.half_span); SAME(bearing.k1); SAME(bearing.k3); SAME(bearing.radial_damping);
  SAME(bearing.axial_stiffness); SAME(bearing.axial_damping);
  SAME(drive.speed); SAME(drive.stiffness); SAME(drive.damping);
  SAME(load.torque); SAME(load.inertia); SAME(load.speed_coefficient); SAME(load.stiffness);
  SAME(load.damping);
  SAME(clamping.driving); SAME(clamping.driven); SAME(clamping.sheave_damping);
  SAME(controller.enabled); SAME(controller.target_ratio); SAME(controller.kp); SAME(controller.ki);
  SAME(ramp.time); SAME(damping.scale);
  SAME(integrator.method); SAME(integrator.step);
  SAME(run.t_end); SAME(run.sample_interval); SAME(run.snapshot_interval); SAME(run.tracked_pin);
  SAME(run.tracked_link);
  SAME(resolved_toml);
#undef SAME
}

TEST(ConfigTest, ReferenceMatchesModel) {
  const Config c = load_config(kConfigDir + "reference.toml");
  EXPECT_EQ(c.chain.links, 84);
  EXPECT_EQ(c.chain.plates_per_link, 12);
  EXPECT_DOUBLE_EQ(c.chain.pitch, 8.0e-3);
  EXPECT_DOUBLE_EQ(c.geometry.centre_distance, 0.160);
  EXPECT_DOUBLE_EQ(c.geometry.ratio, 1.0);
  EXPECT_DOUBLE_EQ(c.pin.ea, 2.7e6);
  EXPECT_DOUBLE_EQ(c.pin.ei, 2.9);
  EXPECT_EQ(c.rocker.stations, 4);
  EXPECT_DOUBLE_EQ(c.rocker.stiffness, 7.9e10);
  EXPECT_DOUBLE_EQ(c.pulley_contact.stiffness, 2.2e10);
  EXPECT_EQ(c.friction.law, FrictionLaw::nonsmooth);
  EXPECT_DOUBLE_EQ(c.friction.f0, 0.09);
  EXPECT_DOUBLE_EQ(c.friction.v0, 1.0e-3);
  EXPECT_DOUBLE_EQ(c.sheave.cone_angle, 11.0);
  EXPECT_DOUBLE_EQ(c.bearing.k3, 1.0e16);
  EXPECT_DOUBLE_EQ(c.drive.speed, 209.4);
  EXPECT_DOUBLE_EQ(c.load.torque, 150.0);
  EXPECT_DOUBLE_EQ(c.clamping.driving, 25.0e3);
  EXPECT_DOUBLE_EQ(c.clamping.driven, 30.0e3);
  EXPECT_DOUBLE_EQ(c.ramp.time, 2.0e-3);
  EXPECT_EQ(c.integrator.method, IntegratorMethod::ros34pw2);
  EXPECT_DOUBLE_EQ(c.integrator.step, 1.0e-5 / 4);
  EXPECT_TRUE(c.integrator.w_shafts);
  EXPECT_DOUBLE_EQ(c.integrator.settle_time, 2.0e-3);  // not given: the end of the ramp
  EXPECT_DOUBLE_EQ(c.run.t_end, 2.0e-2);
  EXPECT_DOUBLE_EQ(c.run.sample_interval, 1.0e-5);
  EXPECT_DOUBLE_EQ(c.run.snapshot_interval, 1.0e-4);
}

TEST(ConfigTest, ReferenceEqualsStructDefaults) {
  // The struct defaults are the reference model; an empty file gives them too.
  Config defaults = parse_config("");
  expect_same(load_config(kConfigDir + "reference.toml"), defaults);
  Config plain;
  plain.resolved_toml = defaults.resolved_toml;
  expect_same(plain, defaults);
}

TEST(ConfigTest, EveryShippedConfigLoads) {
  // Every shipped config runs the advised method at a step that divides its intervals (its
  // own, checked against RK4: docs/integrators.md 12.6).
  for (const char* name : {"reference.toml", "reference-steady.toml", "reference-shift.toml", "mini.toml", "ratio-0.5.toml",
                           "ratio-2.0.toml", "launch.toml"}) {
    SCOPED_TRACE(name);
    Config c;
    ASSERT_NO_THROW(c = load_config(kConfigDir + name));
    EXPECT_EQ(c.integrator.method, IntegratorMethod::ros34pw2);
    const double per_sample = c.run.sample_interval / c.integrator.step;
    EXPECT_NEAR(per_sample, std::round(per_sample), 1e-9);
    EXPECT_GE(c.integrator.step, 1e-5 / 12 * (1 - 1e-12));
    EXPECT_GE(c.run.t_end, 2e-2);
    EXPECT_DOUBLE_EQ(c.run.sample_interval, 1e-5);
    EXPECT_DOUBLE_EQ(c.run.snapshot_interval, 1e-4);
  }
  const Config mini = load_config(kConfigDir + "mini.toml");
  EXPECT_EQ(mini.chain.links, 30);
  EXPECT_EQ(mini.chain.plates_per_link, 4);
  EXPECT_DOUBLE_EQ(mini.geometry.centre_distance, 0.06);
  EXPECT_DOUBLE_EQ(mini.sheave.outer_radius, 0.035);
  EXPECT_DOUBLE_EQ(mini.sheave.hub_radius, 0.010);
  EXPECT_DOUBLE_EQ(load_config(kConfigDir + "ratio-0.5.toml").geometry.ratio, 0.5);
  EXPECT_DOUBLE_EQ(load_config(kConfigDir + "ratio-2.0.toml").geometry.ratio, 2.0);
}

// The ratio configs are the reference at another ratio; they may rebuild the W-method's
// stiffness more often (integrator.w_k_every), which their start from rest needs.
TEST(ConfigTest, ShippedRatioConfigsDifferFromReferenceOnlyInRatioAndStep) {
  const Config ref = load_config(kConfigDir + "reference.toml");
  for (const char* name : {"ratio-0.5.toml", "ratio-2.0.toml"}) {
    Config c = load_config(kConfigDir + name);
    char step[32];
    std::snprintf(step, sizeof step, "%.17g", c.integrator.step);
    Config r = parse_config(ref.resolved_toml, {"geometry.ratio=" + std::to_string(c.geometry.ratio),
                                                "integrator.w_k_every=" + std::to_string(c.integrator.w_k_every),
                                                std::string("integrator.step=") + step});
    expect_same(c, r);
  }
}

TEST(ConfigTest, OmittedSectionsAndKeysKeepDefaults) {
  const Config c = parse_config("[chain]\nlinks = 50\n");
  EXPECT_EQ(c.chain.links, 50);
  EXPECT_DOUBLE_EQ(c.chain.pitch, 8.0e-3);
  EXPECT_DOUBLE_EQ(c.pin.length, 0.036);
}

// Files and checkpoints written before integrator.startup_step still load: the old
// startup_substeps = n (sub-steps of step / n) becomes startup_step = step / n, also after
// a --step override; a startup_step given beside it wins; a bad n is still refused.
TEST(ConfigTest, OldStartupSubstepsBecomesStartupStep) {
  const Config a = parse_config("[integrator]\nstep = 2e-7\nstartup_substeps = 4\n");
  EXPECT_DOUBLE_EQ(a.integrator.startup_step, 5e-8);
  EXPECT_EQ(a.resolved_toml.find("startup_substeps"), std::string::npos);
  EXPECT_NE(a.resolved_toml.find("startup_step"), std::string::npos);
  const Config b = parse_config("[integrator]\nstartup_substeps = 4\n", {"integrator.step=1e-6"});
  EXPECT_DOUBLE_EQ(b.integrator.startup_step, 2.5e-7);
  const Config c = parse_config("[integrator]\nstartup_substeps = 4\nstartup_step = 1e-8\n");
  EXPECT_DOUBLE_EQ(c.integrator.startup_step, 1e-8);
  EXPECT_THROW(parse_config("[integrator]\nstartup_substeps = 0\n"), ConfigError);
}

TEST(ConfigTest, IntegerAcceptedForDouble) {
  const Config c = parse_config("[load]\ntorque = 84\n");
  EXPECT_DOUBLE_EQ(c.load.torque, 84.0);
}

TEST(ConfigTest, MissingFile) {
  const std::string path = kConfigDir + "no-such-file.toml";
  auto e = expect_error([&] { load_config(path); }, "<file>", path);
  EXPECT_TRUE(contains(e.reason(), "no such file"));
}

TEST(ConfigTest, TomlSyntaxError) {
  auto e = expect_error([] { parse_config("[chain]\nlinks = = 3\n", {}, "broken.toml"); }, "<file>", "broken.toml");
  EXPECT_TRUE(contains(e.reason(), "line 2")) << e.reason();
}

TEST(ConfigTest, UnknownKey) {
  auto e = expect_parse_error("[chain]\nlinkz = 84\n", "chain.linkz", "84");
  EXPECT_TRUE(contains(e.reason(), "unknown key")) << e.reason();
  EXPECT_TRUE(contains(e.reason(), "chain.links")) << e.reason();  // did you mean
}

TEST(ConfigTest, UnknownKeyWithoutSuggestion) {
  auto e = expect_parse_error("[pin]\nwobble = 1.5\n", "pin.wobble", "1.5");
  EXPECT_TRUE(contains(e.reason(), "unknown key")) << e.reason();
  EXPECT_FALSE(contains(e.reason(), "did you mean")) << e.reason();
}

TEST(ConfigTest, UnknownSectionIsNamedAsASection) {
  auto e = expect_parse_error("[chian]\nlinks = 40\n", "[chian]", "");
  EXPECT_TRUE(contains(e.reason(), "unknown section; did you mean '[chain]'")) << e.reason();
  EXPECT_TRUE(contains(e.reason(), "it holds links")) << e.reason();
  e = expect_parse_error("[lod]\ntorque = 3\ninertia = 0.1\n", "[lod]", "");
  EXPECT_TRUE(contains(e.reason(), "'[load]'")) << e.reason();
  EXPECT_TRUE(contains(e.reason(), "line 1")) << e.reason();
  // From --set it is named by the override's key.
  e = expect_override_error("chian.links=40", "chian.links", "40");
  EXPECT_TRUE(contains(e.reason(), "chain.links")) << e.reason();
  EXPECT_TRUE(contains(e.reason(), "(from --set)")) << e.reason();
}

TEST(ConfigTest, EveryProblemOfAFileIsReported) {
  auto e = expect_parse_error("[chain]\nlinkz = 3\npich = 2\n[lod]\ntorque = 3\n[pin]\nea = -1\n", "chain.linkz", "3");
  const std::string all = e.what();
  for (const char* what : {"chain.linkz = 3: unknown key; did you mean 'chain.links'? (<string> line 2)",
                           "\nconfiguration error: chain.pich = 2: unknown key; did you mean 'chain.pitch'?",
                           "\nconfiguration error: [lod]: unknown section", "\nconfiguration error: pin.ea = -1: must be positive"})
    EXPECT_TRUE(contains(all, what)) << what << " missing: " << all;
}

TEST(ConfigTest, ShortcutOptionsAreNamedInMessages) {
  try {
    parse_config("", {"integrator.step=-1e-8"}, "<string>", {{"integrator.step", "--step"}});
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_TRUE(contains(e.what(), "(from --step)")) << e.what();
  }
}

TEST(ConfigTest, SuggestsTheNameAPrefixBegins) {
  auto e = expect_override_error("integrator.method=ros34pw", "integrator.method", "ros34pw");
  EXPECT_TRUE(contains(e.reason(), "did you mean 'ros34pw2'")) << e.reason();
}

// A prefix of two names (ros34pw2, ros34prw) suggests neither, nor a name nearer by edits
// (ros2): the accepted names are listed.
TEST(ConfigTest, SuggestsNothingForAPrefixOfTwoNames) {
  auto e = expect_override_error("integrator.method=ros34", "integrator.method", "ros34");
  EXPECT_FALSE(contains(e.reason(), "did you mean")) << e.reason();
  EXPECT_TRUE(contains(e.reason(), "\"ros34pw2\", \"ros34prw\"")) << e.reason();
}

TEST(ConfigTest, MissingFileSaysItCannotBeRead) {
  try {
    load_config("/no/such/cvt.toml");
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_EQ(std::string(e.what()), "configuration error: cannot read the configuration file '/no/such/cvt.toml': no such file");
  }
}

TEST(ConfigTest, TopLevelKeyIsUnknown) {
  auto e = expect_parse_error("links = 40\n", "links", "40");
  EXPECT_TRUE(contains(e.reason(), "unknown key")) << e.reason();
  EXPECT_TRUE(contains(e.reason(), "chain.links")) << e.reason();
}

TEST(ConfigTest, StringForNumber) {
  auto e = expect_parse_error("[chain]\npitch = \"8e-3\"\n", "chain.pitch", "8e-3");
  EXPECT_TRUE(contains(e.reason(), "floating-point")) << e.reason();
}

TEST(ConfigTest, DoubleForInteger) {
  auto e = expect_parse_error("[chain]\nlinks = 84.5\n", "chain.links", "84.5");
  EXPECT_TRUE(contains(e.reason(), "integer")) << e.reason();
  expect_parse_error("[chain]\nlinks = 84.0\n", "chain.links", "84.0");
}

TEST(ConfigTest, BooleanOnlyForEnabled) {
  expect_parse_error("[controller]\nenabled = 1\n", "controller.enabled", "1");
  expect_parse_error("[controller]\nkp = true\n", "controller.kp", "true");
  EXPECT_TRUE(parse_config("[controller]\nenabled = true\n").controller.enabled);
}

TEST(ConfigTest, NonPositivePhysicalQuantity) {
  auto e = expect_parse_error("[pin]\nlength = -0.036\n", "pin.length", "-0.036");
  EXPECT_TRUE(contains(e.reason(), "> 0")) << e.reason();
  expect_parse_error("[chain]\nplate_mass = 0.0\n", "chain.plate_mass", "0.0");
  expect_parse_error("[integrator]\nstep = 0\n", "integrator.step", "0");
  expect_parse_error("[friction]\nf0 = -0.1\n", "friction.f0", "-0.1");
  expect_parse_error("[chain]\nplate_damping = -1.0\n", "chain.plate_damping", "-1.0");
  expect_parse_error("[drive]\nspeed = -5.0\n", "drive.speed", "-5.0");
  // Zero is fine where it means "off".
  const Config c = parse_config("[damping]\nscale = 0\n[ramp]\ntime = 0.0\n[run]\nsnapshot_interval = 0\n");
  EXPECT_EQ(c.damping.scale, 0.0);
  EXPECT_EQ(c.run.snapshot_interval, 0.0);
}

TEST(ConfigTest, IntegerRanges) {
  expect_parse_error("[chain]\nlinks = 2\n", "chain.links", "2");
  expect_parse_error("[chain]\nlinks = 10001\n", "chain.links", "10001");
  expect_parse_error("[chain]\nplates_per_link = 0\n", "chain.plates_per_link", "0");
  expect_parse_error("[rocker]\nstations = 17\n", "rocker.stations", "17");
  expect_parse_error("[run]\ntracked_pin = 84\n", "run.tracked_pin", "84");
  expect_parse_error("[run]\ntracked_link = -1\n", "run.tracked_link", "-1");
  EXPECT_EQ(parse_config("[run]\ntracked_pin = 83\n").run.tracked_pin, 83);
}

TEST(ConfigTest, NanAndInfRejected) {
  expect_parse_error("[load]\ntorque = nan\n", "load.torque", "nan");
  expect_parse_error("[run]\nt_end = inf\n", "run.t_end", "inf");
}

TEST(ConfigTest, CrossKeyChecks) {
  expect_parse_error("[sheave]\nhub_radius = 0.09\n", "sheave.hub_radius", "0.09");
  expect_parse_error("[sheave]\ncone_angle = 45.0\n", "sheave.cone_angle", "45.0");
  expect_parse_error("[rocker]\nradius = 1.0e-3\n", "rocker.radius", "0.001");
  expect_parse_error("[chain]\nplate_spread = 0.04\n", "chain.plate_spread", "0.04");
  expect_parse_error("[run]\nsample_interval = 1e-9\n", "run.sample_interval", "1e-9");
  expect_parse_error("[integrator]\nstep = 5e-2\n[run]\nsample_interval = 5e-2\nsnapshot_interval = 0\n", "run.t_end", "0.02");
  auto e = expect_parse_error("[chain]\nlinks = 30\n[run]\ntracked_link = 40\n", "run.tracked_link", "40");
  EXPECT_TRUE(contains(e.reason(), "30")) << e.reason();
}

// The target profile is an array of [time, ratio] pairs with times that do not decrease;
// it round-trips through the resolved TOML.
TEST(ConfigTest, TargetProfile) {
  const Config c = parse_config("[controller]\ntarget_profile = [[0, 1.0], [0.1, 1.2], [0.1, 0.8]]\n");
  ASSERT_EQ(c.controller.target_profile.size(), 3u);
  EXPECT_EQ(c.controller.target_profile[1][0], 0.1);
  EXPECT_EQ(c.controller.target_profile[2][1], 0.8);
  EXPECT_EQ(parse_config(c.resolved_toml).controller.target_profile, c.controller.target_profile);
  EXPECT_TRUE(parse_config("").controller.target_profile.empty());
  auto e = expect_override_error("controller.target_profile=[[0.1, 1.0], [0.05, 1.2]]", "controller.target_profile", "[[0.1, 1.0], [0.05, 1.2]]");
  EXPECT_TRUE(contains(e.reason(), "point 2 [0.05, 1.2]: the times must not decrease")) << e.reason();
  e = expect_override_error("controller.target_profile=[[0, -1.0]]", "controller.target_profile", "-1");
  EXPECT_TRUE(contains(e.reason(), "ratio must be positive")) << e.reason();
  e = expect_override_error("controller.target_profile=[[0, 1.0, 2.0]]", "controller.target_profile", "2");
  EXPECT_TRUE(contains(e.reason(), "[time, ratio] pair")) << e.reason();
  expect_override_error("controller.target_profile=[[-1, 1.0]]", "controller.target_profile", "-1");
  expect_override_error("controller.target_profile=1.2", "controller.target_profile", "1.2");
}

// Each control has its own gains: kp, ki on F1 without the slip-safe clamping, shift_kp,
// shift_ki on ln(F1/F2) with it; the other pair is refused with the reason.
TEST(ConfigTest, ControllerGainsBelongToTheirControl) {
  auto e = expect_parse_error("[controller]\nclamping_safety = 1.5\nkp = 1e5\n", "controller.kp", "1e5");
  EXPECT_TRUE(contains(e.reason(), "shift_kp")) << e.reason();
  e = expect_parse_error("[controller]\nshift_ki = 100\n", "controller.shift_ki", "100");
  EXPECT_TRUE(contains(e.reason(), "clamping_safety")) << e.reason();
  expect_parse_error("[controller]\nthrust_limit = 1.0\n", "controller.thrust_limit", "1.0");
  EXPECT_NO_THROW(parse_config("[controller]\nclamping_safety = 1.5\nshift_kp = 20\nshift_ki = 400\n"));
}

TEST(ConfigTest, BadFrictionLaw) {
  auto e = expect_parse_error("[friction]\nlaw = \"coulomb\"\n", "friction.law", "coulomb");
  EXPECT_TRUE(contains(e.reason(), "nonsmooth")) << e.reason();
  e = expect_parse_error("[friction]\nlaw = \"smoth\"\n", "friction.law", "smoth");
  EXPECT_TRUE(contains(e.reason(), "did you mean 'smooth'")) << e.reason();
  expect_parse_error("[friction]\nlaw = 1\n", "friction.law", "1");
}

TEST(ConfigTest, BadIntegratorMethod) {
  auto e = expect_parse_error("[integrator]\nmethod = \"euler\"\n", "integrator.method", "euler");
  EXPECT_TRUE(contains(e.reason(), "rk4")) << e.reason();
}

TEST(ConfigTest, FrictionLawNames) {
  EXPECT_STREQ(to_string(FrictionLaw::nonsmooth), "nonsmooth");
  EXPECT_STREQ(to_string(FrictionLaw::smooth), "smooth");
  EXPECT_STREQ(to_string(FrictionLaw::none), "none");
  EXPECT_EQ(parse_config("[friction]\nlaw = \"none\"\n").friction.law, FrictionLaw::none);
}

TEST(ConfigTest, OverridesApply) {
  const Config c = load_config(kConfigDir + "reference.toml",
                               {"friction.law=smooth", "chain.links=40", "integrator.step = 2e-8",
                                "friction.f0=0.1", "controller.enabled=true", "load.torque=84",
                                "geometry.ratio=\"ignored\"", "geometry.ratio=1.5"});
  EXPECT_EQ(c.friction.law, FrictionLaw::smooth);
  EXPECT_EQ(c.chain.links, 40);
  EXPECT_DOUBLE_EQ(c.integrator.step, 2e-8);
  EXPECT_DOUBLE_EQ(c.friction.f0, 0.1);
  EXPECT_TRUE(c.controller.enabled);
  EXPECT_DOUBLE_EQ(c.load.torque, 84.0);
  EXPECT_DOUBLE_EQ(c.geometry.ratio, 1.5);  // the last override of a key wins
  EXPECT_EQ(parse_config("", {"friction.law=\"none\""}).friction.law, FrictionLaw::none);
  // The resolved TOML includes them.
  EXPECT_TRUE(contains(c.resolved_toml, "law = \"smooth\"")) << c.resolved_toml;
  EXPECT_TRUE(contains(c.resolved_toml, "links = 40")) << c.resolved_toml;
  EXPECT_TRUE(contains(c.resolved_toml, "torque = 84.0")) << c.resolved_toml;
}

TEST(ConfigTest, OverrideIntoSectionMissingFromFile) {
  const Config c = parse_config("[chain]\nlinks = 50\n", {"pin.length=0.04"});
  EXPECT_EQ(c.chain.links, 50);
  EXPECT_DOUBLE_EQ(c.pin.length, 0.04);
}

TEST(ConfigTest, MalformedOverride) {
  // Named as the option and its quoted text (which may be empty).
  auto e = expect_override_error("chain.links40", "--set", "'chain.links40'");
  EXPECT_TRUE(contains(e.reason(), "=")) << e.reason();
  expect_override_error("links=40", "--set", "'links=40'");
  expect_override_error(".links=40", "--set", "'.links=40'");
  expect_override_error("chain.=40", "--set", "'chain.=40'");
  expect_override_error("chain.links=", "--set", "'chain.links='");
  expect_override_error("", "--set", "''");
}

// A '#' outside TOML's quotes would make TOML drop the rest of the value as a comment
// (geometry.ratio=0.9#x read as 0.9): refused; inside a string it is the string's.
TEST(ConfigTest, AnOverrideWithACommentIsRefused) {
  auto e = expect_override_error("geometry.ratio=0.9#x", "geometry.ratio", "0.9#x");
  EXPECT_TRUE(contains(e.reason(), "'#' outside quotes")) << e.reason();
  expect_override_error("load.torque=1 # note", "load.torque", "1 # note");
  e = expect_override_error("friction.law=\"a#b\"", "friction.law", "\"a#b\"");
  EXPECT_TRUE(contains(e.reason(), "unknown friction law")) << e.reason();
}

TEST(ConfigTest, OverridesAreValidated) {
  auto e = expect_override_error("chain.linkz=40", "chain.linkz", "40");
  EXPECT_TRUE(contains(e.reason(), "chain.links")) << e.reason();
  expect_override_error("chain.links=40.5", "chain.links", "40.5");
  expect_override_error("chain.pitch=abc", "chain.pitch", "abc");
  expect_override_error("pin.length=-1e-3", "pin.length", "-1e-3");
  expect_override_error("friction.law=coulomb", "friction.law", "coulomb");
  expect_override_error("run.t_end=[1, 2]", "run.t_end", "[1, 2]");
  expect_override_error("chain.links=3\nfoo = 4", "chain.links", "foo");
}

TEST(ConfigTest, ResolvedTomlIsComplete) {
  const Config c = parse_config("");
  for (const char* s : {"[geometry]", "[chain]", "[pin]", "[rocker]", "[pulley_contact]", "[friction]",
                        "[sheave]", "[shaft]", "[bearing]", "[drive]", "[load]", "[clamping]",
                        "[controller]", "[ramp]", "[damping]", "[integrator]", "[run]"})
    EXPECT_TRUE(contains(c.resolved_toml, s)) << s;
  EXPECT_TRUE(contains(c.resolved_toml, "links = 84\n") || contains(c.resolved_toml, "links = 84 "));
  EXPECT_TRUE(contains(c.resolved_toml, "speed_coefficient = 0.0")) << c.resolved_toml;
  EXPECT_TRUE(contains(c.resolved_toml, "enabled = false")) << c.resolved_toml;
}

TEST(ConfigTest, ResolvedTomlRoundTrips) {
  for (const char* name : {"reference.toml", "mini.toml", "ratio-0.5.toml", "ratio-2.0.toml"}) {
    SCOPED_TRACE(name);
    const Config a = load_config(kConfigDir + name);
    expect_same(parse_config(a.resolved_toml), a);
  }
  // Values that need all 17 digits, integers given for doubles, every non-default kind.
  const Config a = parse_config("[geometry]\ncentre_distance = 0.30000000000000004\n",
                                {"friction.law=none", "chain.pitch=0.0081234567890123456", "load.torque=7",
                                 "controller.enabled=true", "controller.kp=1e-300", "bearing.k3=1.7976931348623157e308",
                                 "drive.speed=0", "run.snapshot_interval=0", "sheave.cone_angle=44.999999999999993",
                                 "run.tracked_pin=83", "run.tracked_link=1"});
  const Config b = parse_config(a.resolved_toml);
  expect_same(a, b);
  EXPECT_EQ(a.geometry.centre_distance, 0.1 + 0.2);
  EXPECT_EQ(b.friction.law, FrictionLaw::none);
  EXPECT_EQ(parse_config(b.resolved_toml).resolved_toml, a.resolved_toml);
}

}  // namespace
}  // namespace cvt

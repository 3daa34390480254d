// The results file of a run (docs/output.md): the channels under /observables, the chain's
// snapshots under /particles, /parameters, /profile and /summary, and what a continued
// run reads back from its own file. engine/run.cpp writes it through these.
#pragma once

#include <set>
#include <string>
#include <vector>

#include "engine/io/checkpoint.hpp"
#include "engine/io/h5_writer.hpp"
#include "engine/rhs/profile.hpp"
#include "engine/simulation.hpp"
#include "engine/summary.hpp"

namespace cvt {

// The HDF5 layout of docs/output.md.
class Recorder {
 public:
  Recorder(H5File& f, const Model& m) : f_(f), N_(m.links) {}

  void scalar(const std::string& name, const std::string& unit, double t, double value) {
    const Slot& x = slot(name, unit, {});
    if (declare_only_) return;
    x.value->append(value);
    x.time->append(t);
    x.step->append(step_);
  }
  void vector(const std::string& name, const std::string& unit, double t, const double* v, hsize_t k) {
    const Slot& x = slot(name, unit, {k});
    if (declare_only_) return;
    x.value->append(v);
    x.time->append(t);
    x.step->append(step_);
  }
  // Creates (or opens, in a continued file) every series and its unit without appending:
  // in SWMR mode no object may be created later.
  void declare(const Sample& s, bool snapshots) {
    declare_only_ = true;
    record(s);
    if (snapshots) snapshot(s.t, s.step, {}, {}, {}, {});
    declare_only_ = false;
  }
  // Keeps the first `samples` rows of every observable and `snaps` of every snapshot series.
  void truncate(hsize_t samples, hsize_t snaps) {
    for (H5Series* x : observables_) x->truncate(samples);
    for (H5Series* x : snapshots_) x->truncate(snaps);
  }
  void record(const Sample& s) {
    cursor_ = 0;
    step_ = static_cast<double>(s.step);
    scalar("input_speed", "rad/s", s.t, s.input_speed);
    scalar("output_speed", "rad/s", s.t, s.output_speed);
    scalar("load_speed", "rad/s", s.t, s.load_speed);
    scalar("input_torque", "N m", s.t, s.input_torque);
    scalar("output_torque", "N m", s.t, s.output_torque);
    scalar("load_torque", "N m", s.t, s.load_torque);
    scalar("speed_ratio", "1", s.t, s.speed_ratio);
    scalar("geometric_ratio", "1", s.t, s.geometric_ratio);
    scalar("slip", "1", s.t, slip_of(s.speed_ratio, s.geometric_ratio));
    scalar("efficiency", "1", s.t, s.efficiency);
    scalar("clamping_force_driving", "N", s.t, s.clamp[0]);
    scalar("clamping_force_driven", "N", s.t, s.clamp[1]);
    vector("sheave_position", "m", s.t, s.sheave_position, 2);
    vector("support_force", "N", s.t, s.support_force, 4);
    vector("pin_axial_force", "N", s.t, s.pin_axial_force, 2);
    vector("pin_end_normal_force", "N", s.t, s.pin_end_normal, 4);
    vector("pin_end_friction_force", "N", s.t, s.pin_end_friction, 4);
    scalar("link_tension", "N", s.t, s.link_tension);
    scalar("strand_tension_upper", "N", s.t, s.strand_tension[0]);
    scalar("strand_tension_lower", "N", s.t, s.strand_tension[1]);
    vector("plate_tension", "N", s.t, s.plate_tension.data(), static_cast<int>(s.plate_tension.size()));
    scalar("rocker_force", "N", s.t, s.rocker_force);
    scalar("chain_torsion_angle", "rad", s.t, s.chain_torsion_angle);
    scalar("input_angle", "rad", s.t, s.input_angle);
    scalar("output_angle", "rad", s.t, s.output_angle);
    scalar("load_angle", "rad", s.t, s.load_angle);
    scalar("power_input", "W", s.t, s.power_input);
    scalar("power_output", "W", s.t, s.power_output);
    scalar("power_dissipated", "W", s.t, s.power_dissipated);
    scalar("running_efficiency", "1", s.t, s.running_efficiency);
    scalar("energy_kinetic", "J", s.t, s.energy_kinetic);
    scalar("energy_elastic", "J", s.t, s.energy_elastic);
    scalar("work_input", "J", s.t, s.work_input);
    scalar("work_output", "J", s.t, s.work_output);
    scalar("work_dissipated", "J", s.t, s.work_dissipated);
    scalar("work_clamping", "J", s.t, s.work_clamping);
    scalar("work_contact_switching", "J", s.t, s.work_contact_switching);
    scalar("energy_residual", "J", s.t, s.energy_residual);
  }
  // The snapshot elements of /particles/chain (H5MD time-dependent elements: value, time,
  // step) and the particles group's box (3 dimensions, no periodic boundary).
  void snapshot(double t, long step, const std::vector<double>& pos, const std::vector<double>& tension,
                const std::vector<double>& pin_ends, const std::vector<double>& contact_normal) {
    const hsize_t N = hsize_t(N_);
    if (!snap_init_) {
      particle("position", "m", {N, 3});
      particle("link_tension", "N", {N});
      particle("pin_end_position", "m", {N, 2, 2, 3});
      particle("pin_end_normal_force", "N", {N, 2, 2});
      f_.set_int_attribute("/particles/chain/box", "dimension", 3);
      f_.set_strings_attribute("/particles/chain/box", "boundary", {"none", "none", "none"});
      snap_init_ = true;
    }
    if (declare_only_) return;
    const std::vector<double>* rows[] = {&pos, &tension, &pin_ends, &contact_normal};
    for (std::size_t k = 0; k < 4; ++k) {
      particles_[k].value->append(rows[k]->data());
      particles_[k].time->append(t);
      particles_[k].step->append(static_cast<double>(step));
    }
  }

 private:
  // An observable's value and time series. record() names them in one fixed order: the
  // first call looks them up by path, later calls take them from slots_ by position.
  struct Slot {
    H5Series* value;
    H5Series* time;
    H5Series* step;
  };
  const Slot& slot(const std::string& name, const std::string& unit, std::vector<hsize_t> shape) {
    if (cursor_ == slots_.size()) {
      const std::string at = "/observables/" + name;
      slots_.push_back({&series(name, unit, std::move(shape)), &time(name), &f_.series(at + "/step", {}, 256, true)});
      observables_.push_back(slots_.back().step);
    }
    return slots_[cursor_++];
  }
  // A snapshot element: its value [S][N]..., time [S] in s and step [S].
  void particle(const std::string& name, const std::string& unit, std::vector<hsize_t> shape) {
    const std::string at = "/particles/chain/" + name;
    Slot x{&f_.series(at + "/value", std::move(shape), 16), &f_.series(at + "/time", {}, 256),
           &f_.series(at + "/step", {}, 256, true)};
    f_.set_string_attribute(at + "/value", "unit", unit);
    f_.set_string_attribute(at + "/time", "unit", "s");
    particles_.push_back(x);
    snapshots_.insert(snapshots_.end(), {x.value, x.time, x.step});
  }
  H5Series& series(const std::string& name, const std::string& unit, std::vector<hsize_t> shape) {
    const std::string path = "/observables/" + name + "/value";
    H5Series& s = f_.series(path, shape);
    if (!units_done_.count(name)) {
      f_.set_string_attribute(path, "unit", unit);
      units_done_.insert(name);
      observables_.push_back(&s);
    }
    return s;
  }
  H5Series& time(const std::string& name) {
    const std::string path = "/observables/" + name + "/time";
    H5Series& s = f_.series(path, {});
    if (!units_done_.count(name + "/time")) {
      f_.set_string_attribute(path, "unit", "s");
      units_done_.insert(name + "/time");
      observables_.push_back(&s);
    }
    return s;
  }
  H5File& f_;
  int N_;
  std::vector<Slot> slots_, particles_;
  std::size_t cursor_ = 0;
  double step_ = 0;  // the sample's step count
  bool snap_init_ = false, declare_only_ = false;
  std::set<std::string> units_done_;
  std::vector<H5Series*> observables_, snapshots_;
};

// /parameters: the version, the resolved configuration, the run id and the geometry.
void write_parameters(H5File& f, const Model& m, const std::string& run_id);
// The /profile group: one entry per row of the table.
void write_profile(H5File& f, const Profiler::Report& r);
// The /summary group: every entry an attribute.
void write_summary(H5File& f, const RunSummary& s);
// A new random run id (16 hex digits).
std::string new_run_id();

// The earlier part of a continued run, read back from its file: the rows up to the
// checkpoint on the sample grid, for the summary and the running efficiency's window.
struct FileHistory {
  hsize_t samples = 0, snapshots = 0;
  SummaryChannels channels;
  std::vector<Sample> tail;  // the rows within run.efficiency_window of the checkpoint (t and works)
};

// Opens the run's own file for a continuation, checks that it belongs to the checkpoint and
// holds every sample up to it, and reads the history. Throws std::runtime_error otherwise.
FileHistory continue_file(H5File& f, const Model& m, const Checkpoint& ck, long every_sample, long every_snapshot);

}  // namespace cvt

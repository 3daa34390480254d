#include "engine/io/checkpoint.hpp"

#include <hdf5.h>

#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include "engine/io/files.hpp"
#include "engine/io/h5_writer.hpp"

namespace cvt {

namespace {

struct Closer {
  hid_t id;
  herr_t (*close)(hid_t);
  ~Closer() {
    if (id >= 0) close(id);
  }
};

std::vector<double> read_vector(hid_t file, const std::string& path, const std::string& name) {
  const hid_t d = H5Dopen2(file, name.c_str(), H5P_DEFAULT);
  if (d < 0) throw std::runtime_error("checkpoint " + path + ": no dataset " + name);
  Closer cd{d, H5Dclose};
  const hid_t sp = H5Dget_space(d);
  Closer cs{sp, H5Sclose};
  if (H5Sget_simple_extent_ndims(sp) != 1) throw std::runtime_error("checkpoint " + path + ": " + name + " is not 1-D");
  hsize_t n = 0;
  H5Sget_simple_extent_dims(sp, &n, nullptr);
  std::vector<double> v(n);
  if (n && H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data()) < 0)
    throw std::runtime_error("checkpoint " + path + ": cannot read " + name);
  return v;
}

std::string read_string(hid_t file, const std::string& path, const std::string& name) {
  const hid_t d = H5Dopen2(file, name.c_str(), H5P_DEFAULT);
  if (d < 0) throw std::runtime_error("checkpoint " + path + ": no dataset " + name);
  Closer cd{d, H5Dclose};
  const hid_t type = H5Tcopy(H5T_C_S1);
  Closer ct{type, H5Tclose};
  H5Tset_size(type, H5T_VARIABLE);
  H5Tset_cset(type, H5T_CSET_UTF8);
  char* text = nullptr;
  if (H5Dread(d, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, &text) < 0 || !text)
    throw std::runtime_error("checkpoint " + path + ": cannot read " + name);
  std::string s(text);
  H5free_memory(text);
  return s;
}

// A list of states under one group, each dataset the states' values one after another:
// /checkpoint holds the run's own state, /checkpoint/verify those run.verify kept.
void write_states(H5File& f, const std::string& group, const std::vector<const Checkpoint*>& list) {
  std::vector<double> y, rocker, pulley, clock, energy0, control;
  for (const Checkpoint* c : list) {
    y.insert(y.end(), c->state.data(), c->state.data() + c->state.size());
    for (std::uint8_t v : c->rocker) rocker.push_back(v);
    for (std::uint8_t v : c->pulley) pulley.push_back(v);
    clock.insert(clock.end(), {c->t, c->t0, static_cast<double>(c->steps), static_cast<double>(c->steps0)});
    energy0.push_back(c->energy0);
    control.insert(control.end(), {static_cast<double>(c->halvings), c->halved_at, c->leak,
                                   static_cast<double>(c->leak_from), c->leak_residual, c->leak_work});
  }
  f.write_vector(group + "/state", y);
  f.write_vector(group + "/rocker_status", rocker);
  f.write_vector(group + "/pulley_status", pulley);
  f.write_vector(group + "/clock", clock);
  f.write_vector(group + "/energy0", energy0);
  f.write_vector(group + "/step_control", control);
}

// The n states under a group (n from its clock); without step_control (checkpoints that
// predate it) they continue from no halving.
std::vector<Checkpoint> read_states(hid_t f, const std::string& path, const std::string& group) {
  const std::vector<double> clock = read_vector(f, path, group + "/clock");
  const std::size_t n = clock.size() / 4;
  if (n == 0 || clock.size() != 4 * n) throw std::runtime_error("checkpoint " + path + ": " + group + "/clock must hold 4 numbers per state");
  const auto split = [&](const std::string& name, std::size_t per) {
    std::vector<double> v = read_vector(f, path, group + "/" + name);
    if (v.size() % n != 0 || (per && v.size() != per * n))
      throw std::runtime_error("checkpoint " + path + ": " + group + "/" + name + " does not hold " +
                               std::to_string(n) + " equal parts");
    return v;
  };
  const std::vector<double> y = split("state", 0), rocker = split("rocker_status", 0), pulley = split("pulley_status", 0),
                            e0 = split("energy0", 1);
  const bool control = H5Lexists(f, (group + "/step_control").c_str(), H5P_DEFAULT) > 0;
  const std::vector<double> sc = control ? split("step_control", 6) : std::vector<double>{};
  std::vector<Checkpoint> out(n);
  const std::size_t ny = y.size() / n, nr = rocker.size() / n, np = pulley.size() / n;
  for (std::size_t i = 0; i < n; ++i) {
    Checkpoint& c = out[i];
    c.state = Eigen::Map<const Eigen::VectorXd>(y.data() + i * ny, static_cast<Eigen::Index>(ny));
    c.rocker.assign(rocker.begin() + static_cast<long>(i * nr), rocker.begin() + static_cast<long>((i + 1) * nr));
    c.pulley.assign(pulley.begin() + static_cast<long>(i * np), pulley.begin() + static_cast<long>((i + 1) * np));
    c.t = clock[4 * i], c.t0 = clock[4 * i + 1];
    c.steps = static_cast<long>(clock[4 * i + 2]), c.steps0 = static_cast<long>(clock[4 * i + 3]);
    c.energy0 = e0[i];
    if (control) {
      const double* s = sc.data() + 6 * i;
      c.halvings = static_cast<int>(s[0]), c.halved_at = s[1], c.leak = s[2];
      c.leak_from = static_cast<long>(s[3]), c.leak_residual = s[4], c.leak_work = s[5];
    }
  }
  return out;
}

}  // namespace

void write_checkpoint(const std::string& path, const Checkpoint& c) {
  // Made in memory and written in one durable replace: a full disk or a crash leaves the
  // previous checkpoint as it was.
  std::vector<unsigned char> bytes;
  {
    H5File f = H5File::create_in_memory(path);
    f.write_string("/parameters/config", c.config_toml);
    write_states(f, "/checkpoint", {&c});
    if (!c.verify_states.empty()) {
      std::vector<const Checkpoint*> kept;
      for (const Checkpoint& k : c.verify_states) kept.push_back(&k);
      write_states(f, "/checkpoint/verify", kept);
    }
    if (!c.run_id.empty()) f.write_string("/checkpoint/run_id", c.run_id);
    if (!c.output.empty()) f.write_string("/checkpoint/output", c.output);
    if (!c.stopped.empty()) f.write_string("/checkpoint/stopped", c.stopped);
    bytes = f.image();
    f.close();
  }
  replace_file(path, bytes.data(), bytes.size());
}

Checkpoint read_checkpoint(const std::string& path) {
  h5_silence_error_printing();
  const hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (f < 0) throw std::runtime_error("cannot open checkpoint " + path);
  Closer cf{f, H5Fclose};
  std::vector<Checkpoint> own = read_states(f, path, "/checkpoint");
  if (own.size() != 1) throw std::runtime_error("checkpoint " + path + ": /checkpoint/clock must hold 4 numbers");
  Checkpoint c = std::move(own[0]);
  c.config_toml = read_string(f, path, "/parameters/config");
  if (H5Lexists(f, "/checkpoint/verify", H5P_DEFAULT) > 0) c.verify_states = read_states(f, path, "/checkpoint/verify");
  for (const Checkpoint& k : c.verify_states)
    if (k.state.size() != c.state.size() || k.rocker.size() != c.rocker.size() || k.pulley.size() != c.pulley.size())
      throw std::runtime_error("checkpoint " + path + ": a state of /checkpoint/verify is not the run's size");
  for (auto [name, to] : {std::pair{"/checkpoint/run_id", &c.run_id}, std::pair{"/checkpoint/output", &c.output},
                          std::pair{"/checkpoint/stopped", &c.stopped}})
    if (H5Lexists(f, name, H5P_DEFAULT) > 0) *to = read_string(f, path, name);
  return c;
}

}  // namespace cvt

#include "engine/io/checkpoint.hpp"

#include <hdf5.h>

#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include "engine/io/files.hpp"
#include "engine/io/h5_writer.hpp"

namespace cvt {

namespace {

std::vector<double> to_doubles(const std::vector<std::uint8_t>& v) { return {v.begin(), v.end()}; }

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

}  // namespace

void write_checkpoint(const std::string& path, const Checkpoint& c) {
  // Made in memory and written in one durable replace: a full disk or a crash leaves the
  // previous checkpoint as it was.
  std::vector<unsigned char> bytes;
  {
    H5File f = H5File::create_in_memory(path);
    f.write_string("/parameters/config", c.config_toml);
    f.write_vector("/checkpoint/state", std::vector<double>(c.state.data(), c.state.data() + c.state.size()));
    f.write_vector("/checkpoint/rocker_status", to_doubles(c.rocker));
    f.write_vector("/checkpoint/pulley_status", to_doubles(c.pulley));
    f.write_vector("/checkpoint/clock", {c.t, c.t0, static_cast<double>(c.steps), static_cast<double>(c.steps0)});
    f.write_vector("/checkpoint/energy0", {c.energy0});
    f.write_vector("/checkpoint/step_control", {static_cast<double>(c.halvings), c.halved_at, c.leak,
                                                static_cast<double>(c.leak_from), c.leak_residual, c.leak_work});
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
  Checkpoint c;
  c.config_toml = read_string(f, path, "/parameters/config");
  const std::vector<double> y = read_vector(f, path, "/checkpoint/state");
  c.state = Eigen::Map<const Eigen::VectorXd>(y.data(), static_cast<Eigen::Index>(y.size()));
  for (double v : read_vector(f, path, "/checkpoint/rocker_status")) c.rocker.push_back(static_cast<std::uint8_t>(v));
  for (double v : read_vector(f, path, "/checkpoint/pulley_status")) c.pulley.push_back(static_cast<std::uint8_t>(v));
  const std::vector<double> clock = read_vector(f, path, "/checkpoint/clock");
  if (clock.size() != 4) throw std::runtime_error("checkpoint " + path + ": clock must hold 4 numbers");
  c.t = clock[0], c.t0 = clock[1], c.steps = static_cast<long>(clock[2]), c.steps0 = static_cast<long>(clock[3]);
  const std::vector<double> e0 = read_vector(f, path, "/checkpoint/energy0");
  if (e0.size() != 1) throw std::runtime_error("checkpoint " + path + ": energy0 must hold 1 number");
  c.energy0 = e0[0];
  if (H5Lexists(f, "/checkpoint/step_control", H5P_DEFAULT) > 0) {
    const std::vector<double> sc = read_vector(f, path, "/checkpoint/step_control");
    if (sc.size() != 6) throw std::runtime_error("checkpoint " + path + ": step_control must hold 6 numbers");
    c.halvings = static_cast<int>(sc[0]), c.halved_at = sc[1], c.leak = sc[2];
    c.leak_from = static_cast<long>(sc[3]), c.leak_residual = sc[4], c.leak_work = sc[5];
  }
  for (auto [name, to] : {std::pair{"/checkpoint/run_id", &c.run_id}, std::pair{"/checkpoint/output", &c.output},
                          std::pair{"/checkpoint/stopped", &c.stopped}})
    if (H5Lexists(f, name, H5P_DEFAULT) > 0) *to = read_string(f, path, name);
  return c;
}

}  // namespace cvt

// The HDF5 layout written by `cvt-engine run` (docs/output.md): one real run of
// configs/mini.toml, then the file is inspected with the HDF5 C API.
#include <gtest/gtest.h>
#include <hdf5.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <random>
#include <string>
#include <type_traits>
#include <variant>
#include <vector>

#include <nlohmann/json.hpp>

#include "engine/summary.hpp"
#include "tests/test_util.hpp"

namespace cvt {
namespace {

namespace fs = std::filesystem;

using test::shell_quote;

constexpr int kLinks = 30;       // configs/mini.toml
constexpr hsize_t kPlates = 4;    // configs/mini.toml chain.plates_per_link
constexpr hsize_t kSamples = 31; // t = 0, 1e-6, ..., 3e-5
constexpr hsize_t kSnapshots = 4;  // t = 0, 1e-5, 2e-5, 3e-5

// Closes an HDF5 id of any kind on scope exit.
struct Id {
  hid_t id = H5I_INVALID_HID;
  Id() = default;
  explicit Id(hid_t i) : id(i) {}
  Id(const Id&) = delete;
  Id& operator=(const Id&) = delete;
  ~Id() {
    if (id < 0) return;
    switch (H5Iget_type(id)) {
      case H5I_FILE: H5Fclose(id); break;
      case H5I_GROUP: H5Gclose(id); break;
      case H5I_DATASET: H5Dclose(id); break;
      case H5I_DATASPACE: H5Sclose(id); break;
      case H5I_DATATYPE: H5Tclose(id); break;
      case H5I_ATTR: H5Aclose(id); break;
      case H5I_GENPROP_LST: H5Pclose(id); break;
      default: break;
    }
  }
  operator hid_t() const { return id; }
  bool ok() const { return id >= 0; }
};

struct DatasetInfo {
  std::vector<hsize_t> dims, maxdims;
  bool chunked = false, deflate = false;
};

class OutputLayoutTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    std::random_device rd;
    dir_ = new fs::path(fs::temp_directory_path() /
                        ("cvt_output_layout_test_" + std::to_string(::getpid()) + "_" + std::to_string(rd())));
    fs::create_directories(*dir_);
    file_ = new fs::path(*dir_ / "layout.h5");
    const std::string cfg = std::string(CVT_SOURCE_DIR) + "/configs/mini.toml";
    const std::string cmd = "cd " + shell_quote(dir_->string()) + " && " + shell_quote(CVT_ENGINE_EXE) + " run " +
                            shell_quote(cfg) +
                            " --method rk4 --step 1e-8 --t-end 3e-5 --set run.sample_interval=1e-6 --set run.snapshot_interval=1e-5"
                            " --quiet"
                            " --out " + shell_quote(file_->string()) + " >" +
                            shell_quote((*dir_ / "stdout.txt").string()) + " 2>" +
                            shell_quote((*dir_ / "stderr.txt").string());
    const int status = std::system(cmd.c_str());
    exit_code_ = status != -1 && WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  }
  static void TearDownTestSuite() {
    std::error_code ec;
    fs::remove_all(*dir_, ec);
    delete dir_;
    delete file_;
  }

  void SetUp() override {
    ASSERT_EQ(exit_code_, 0) << "cvt-engine run failed; see " << (*dir_ / "stderr.txt");
    ASSERT_TRUE(fs::exists(*file_));
    f_.id = H5Fopen(file_->c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    ASSERT_TRUE(f_.ok()) << "cannot open " << *file_;
  }

  bool exists(const std::string& path) const {
    // Check each component: H5Lexists fails on a missing intermediate group.
    std::string partial;
    size_t pos = 1;
    while (pos <= path.size()) {
      const size_t next = path.find('/', pos);
      partial = path.substr(0, next);
      if (H5Lexists(f_, partial.c_str(), H5P_DEFAULT) <= 0) return false;
      if (next == std::string::npos) break;
      pos = next + 1;
    }
    return true;
  }

  DatasetInfo info(const std::string& path) const {
    DatasetInfo r;
    Id d(H5Dopen2(f_, path.c_str(), H5P_DEFAULT));
    if (!d.ok()) {
      ADD_FAILURE() << "cannot open dataset " << path;
      return r;
    }
    Id sp(H5Dget_space(d));
    const int rank = H5Sget_simple_extent_ndims(sp);
    r.dims.resize(rank);
    r.maxdims.resize(rank);
    H5Sget_simple_extent_dims(sp, r.dims.data(), r.maxdims.data());
    Id dcpl(H5Dget_create_plist(d));
    r.chunked = H5Pget_layout(dcpl) == H5D_CHUNKED;
    unsigned flags = 0, cd[8];
    size_t ncd = 8;
    char name[64];
    unsigned fc = 0;
    r.deflate = H5Pget_filter_by_id2(dcpl, H5Z_FILTER_DEFLATE, &flags, &ncd, cd, sizeof name, name, &fc) >= 0;
    return r;
  }

  std::vector<double> read_doubles(const std::string& path) const {
    Id d(H5Dopen2(f_, path.c_str(), H5P_DEFAULT));
    if (!d.ok()) {
      ADD_FAILURE() << "cannot open dataset " << path;
      return {};
    }
    Id sp(H5Dget_space(d));
    const hssize_t n = H5Sget_simple_extent_npoints(sp);
    std::vector<double> v(n > 0 ? n : 0);
    if (n > 0 && H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data()) < 0)
      ADD_FAILURE() << "cannot read " << path;
    return v;
  }

  // Reads a scalar string (variable- or fixed-length) from an attribute or a dataset.
  static std::string read_string(hid_t obj, hid_t type, bool attribute) {
    if (H5Tget_class(type) != H5T_STRING) {
      ADD_FAILURE() << "not a string type";
      return {};
    }
    if (H5Tis_variable_str(type) > 0) {
      Id mem(H5Tcopy(H5T_C_S1));
      H5Tset_size(mem, H5T_VARIABLE);
      H5Tset_cset(mem, H5Tget_cset(type));
      char* buf = nullptr;
      const herr_t rc = attribute ? H5Aread(obj, mem, &buf) : H5Dread(obj, mem, H5S_ALL, H5S_ALL, H5P_DEFAULT, &buf);
      if (rc < 0 || !buf) {
        ADD_FAILURE() << "cannot read string";
        return {};
      }
      std::string s(buf);
      H5free_memory(buf);
      return s;
    }
    const size_t size = H5Tget_size(type);
    std::string s(size, '\0');
    Id mem(H5Tcopy(type));
    const herr_t rc = attribute ? H5Aread(obj, mem, s.data()) : H5Dread(obj, mem, H5S_ALL, H5S_ALL, H5P_DEFAULT, s.data());
    if (rc < 0) ADD_FAILURE() << "cannot read string";
    s.resize(std::strlen(s.c_str()));
    return s;
  }

  std::string string_attribute(const std::string& object, const std::string& name) const {
    if (H5Aexists_by_name(f_, object.c_str(), name.c_str(), H5P_DEFAULT) <= 0) {
      ADD_FAILURE() << object << " has no attribute '" << name << "'";
      return {};
    }
    Id a(H5Aopen_by_name(f_, object.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT));
    Id t(H5Aget_type(a));
    if (H5Tget_class(t) != H5T_STRING) {
      ADD_FAILURE() << object << "@" << name << " is not a string";
      return {};
    }
    return read_string(a, t, true);
  }

  std::string string_dataset(const std::string& path) const {
    Id d(H5Dopen2(f_, path.c_str(), H5P_DEFAULT));
    if (!d.ok()) {
      ADD_FAILURE() << "cannot open dataset " << path;
      return {};
    }
    Id t(H5Dget_type(d));
    if (H5Tget_class(t) != H5T_STRING) {
      ADD_FAILURE() << path << " is not a string";
      return {};
    }
    return read_string(d, t, false);
  }

  // Time series: 1-D extendible, chunked, deflated, increasing from 0.
  void check_time(const std::string& path, hsize_t expected_rows, double interval) const {
    SCOPED_TRACE(path);
    ASSERT_TRUE(exists(path));
    const DatasetInfo ti = info(path);
    ASSERT_EQ(ti.dims.size(), 1u);
    EXPECT_EQ(ti.dims[0], expected_rows);
    EXPECT_EQ(ti.maxdims[0], H5S_UNLIMITED);
    EXPECT_TRUE(ti.chunked);
    EXPECT_TRUE(ti.deflate);
    const std::vector<double> t = read_doubles(path);
    ASSERT_EQ(t.size(), expected_rows);
    EXPECT_EQ(t[0], 0.0);
    for (size_t i = 0; i < t.size(); ++i) {
      EXPECT_TRUE(std::isfinite(t[i])) << i;
      EXPECT_NEAR(t[i], i * interval, 1e-12) << i;
      if (i > 0) {
        EXPECT_GT(t[i], t[i - 1]) << i;
      }
    }
  }

  // Value series [rows] + row_shape: extendible, chunked, deflated, finite, with a unit.
  void check_value(const std::string& path, hsize_t rows, const std::vector<hsize_t>& row_shape) const {
    SCOPED_TRACE(path);
    ASSERT_TRUE(exists(path));
    const DatasetInfo vi = info(path);
    ASSERT_EQ(vi.dims.size(), 1 + row_shape.size());
    EXPECT_EQ(vi.dims[0], rows);
    for (size_t k = 0; k < row_shape.size(); ++k) EXPECT_EQ(vi.dims[k + 1], row_shape[k]) << "dimension " << k + 1;
    EXPECT_EQ(vi.maxdims[0], H5S_UNLIMITED);
    EXPECT_TRUE(vi.chunked);
    EXPECT_TRUE(vi.deflate);
    EXPECT_FALSE(string_attribute(path, "unit").empty());
    const std::vector<double> v = read_doubles(path);
    hsize_t n = rows;
    for (hsize_t d : row_shape) n *= d;
    ASSERT_EQ(v.size(), n);
    for (size_t i = 0; i < v.size(); ++i) ASSERT_TRUE(std::isfinite(v[i])) << "element " << i << " = " << v[i];
  }

  static fs::path* dir_;
  static fs::path* file_;
  static int exit_code_;
  Id f_;
};

fs::path* OutputLayoutTest::dir_ = nullptr;
fs::path* OutputLayoutTest::file_ = nullptr;
int OutputLayoutTest::exit_code_ = -1;

TEST_F(OutputLayoutTest, RunRenamedPartialFile) {
  EXPECT_FALSE(fs::exists(file_->string() + ".partial"));
}

TEST_F(OutputLayoutTest, Observables) {
  const std::vector<std::string> scalars = {
      "input_speed",     "output_speed",  "input_torque",    "output_torque",  "speed_ratio",
      "geometric_ratio", "efficiency",    "clamping_force_driving", "clamping_force_driven", "link_tension",
      "strand_tension_upper", "strand_tension_lower",
      "energy_kinetic",  "energy_elastic", "work_input",     "work_output",    "work_dissipated",
      "energy_residual", "rocker_force",  "chain_torsion_angle", "input_angle", "output_angle", "load_angle",
      "power_input",     "power_output",  "power_dissipated", "running_efficiency"};
  for (const auto& name : scalars) {
    const std::string base = "/observables/" + name;
    check_time(base + "/time", kSamples, 1e-6);
    check_value(base + "/value", kSamples, {});
  }
  check_time("/observables/pin_axial_force/time", kSamples, 1e-6);
  check_value("/observables/pin_axial_force/value", kSamples, {2});
  check_value("/observables/plate_tension/value", kSamples, {kPlates});
}

// The new channels against the ones they derive from.
TEST_F(OutputLayoutTest, ChannelsAgreeWithEachOther) {
  const auto plates = read_doubles("/observables/plate_tension/value");
  const auto link = read_doubles("/observables/link_tension/value");
  ASSERT_EQ(plates.size(), kPlates * link.size());
  for (size_t i = 0; i < link.size(); ++i) {
    double sum = 0;
    for (hsize_t k = 0; k < kPlates; ++k) sum += plates[i * kPlates + k];
    EXPECT_NEAR(sum, link[i], 1e-9 * (1 + std::abs(link[i]))) << i;
  }
  // Angles integrate speeds (trapezoid over 1 us samples; RK4 is far more accurate).
  const auto phi = read_doubles("/observables/input_angle/value");
  const auto w = read_doubles("/observables/input_speed/value");
  for (size_t i = 1; i < phi.size(); ++i)
    EXPECT_NEAR(phi[i] - phi[i - 1], 0.5e-6 * (w[i] + w[i - 1]), 1e-3 * 1e-6 * std::abs(w[i]) + 1e-12) << i;
  const auto pin = read_doubles("/observables/power_input/value");
  const auto M = read_doubles("/observables/input_torque/value");
  for (size_t i = 0; i < pin.size(); ++i) EXPECT_NEAR(pin[i], M[i] * w[i], 1e-9 * (1 + std::abs(pin[i])));
  for (double p : read_doubles("/observables/power_dissipated/value")) EXPECT_GE(p, 0.0);
  for (double f : read_doubles("/observables/rocker_force/value")) EXPECT_GE(f, 0.0);
}

TEST_F(OutputLayoutTest, ChainSnapshots) {
  check_time("/particles/chain/position/time", kSnapshots, 1e-5);
  check_value("/particles/chain/position/value", kSnapshots, {kLinks, 3});
  check_time("/particles/chain/link_tension/time", kSnapshots, 1e-5);
  check_value("/particles/chain/link_tension/value", kSnapshots, {kLinks});
}

TEST_F(OutputLayoutTest, Parameters) {
  const std::string cfg = string_attribute("/parameters", "config");
  EXPECT_NE(cfg.find("[chain]"), std::string::npos) << cfg;
  EXPECT_NE(cfg.find("links = 30"), std::string::npos) << cfg;
  EXPECT_NE(cfg.find("sample_interval = 1e-6"), std::string::npos) << cfg;
  EXPECT_FALSE(string_attribute("/parameters", "version").empty());
  EXPECT_EQ(string_attribute("/parameters", "run_id").size(), 16u);
}

// The kind of an attribute's type: strings are variable-length UTF-8 (h5py reads them as
// str), flags and counts integers.
H5T_class_t attribute_class(hid_t file, const char* object, const char* name, bool* utf8_vlen = nullptr) {
  const hid_t a = H5Aopen_by_name(file, object, name, H5P_DEFAULT, H5P_DEFAULT);
  if (a < 0) return H5T_NO_CLASS;
  const hid_t t = H5Aget_type(a);
  const H5T_class_t c = H5Tget_class(t);
  if (utf8_vlen) *utf8_vlen = c == H5T_STRING && H5Tis_variable_str(t) > 0 && H5Tget_cset(t) == H5T_CSET_UTF8;
  H5Tclose(t);
  H5Aclose(a);
  return c;
}

TEST_F(OutputLayoutTest, SummaryAndProfileAttributes) {
  for (const char* name : {"status", "method", "controller", "reasons", "warnings"}) {
    bool utf8 = false;
    EXPECT_EQ(attribute_class(f_, "/summary", name, &utf8), H5T_STRING) << name;
    EXPECT_TRUE(utf8) << name << " is not a variable-length UTF-8 string";
  }
  for (const char* name : {"efficiency_meaningful", "interrupted", "steps"})
    EXPECT_EQ(attribute_class(f_, "/summary", name), H5T_INTEGER) << name;
  for (const char* name : {"speed_ratio", "geometric_ratio", "slip", "efficiency", "window_start"})
    EXPECT_EQ(attribute_class(f_, "/summary", name), H5T_FLOAT) << name;
  for (const char* name : {"steps", "threads", "numa_nodes"})
    EXPECT_EQ(attribute_class(f_, "/profile", name), H5T_INTEGER) << name;
  bool utf8 = false;
  EXPECT_EQ(attribute_class(f_, "/profile", "rows", &utf8), H5T_STRING);
  EXPECT_TRUE(utf8);
  for (const char* object : {"/parameters", "/profile"})
    for (const char* name : {"config", "version", "scheduler"})
      if (attribute_class(f_, object, name) == H5T_STRING) {
        bool u = false;
        attribute_class(f_, object, name, &u);
        EXPECT_TRUE(u) << object << "@" << name;
      }
  // A run that ends in the ramp is not steady.
  EXPECT_NE(string_attribute("/summary", "status"), "steady");
}

// /summary holds every entry of the summary's table, typed by its member: doubles as
// doubles, counts and flags as integers, text as UTF-8 strings.
TEST_F(OutputLayoutTest, SummaryHoldsEveryEntryOfTheTable) {
  for (const SummaryField& e : summary_fields()) {
    const std::string name(e.name);
    bool utf8 = false;
    const H5T_class_t c = attribute_class(f_, "/summary", name.c_str(), &utf8);
    std::visit(
        [&](auto m) {
          using T = std::decay_t<decltype(RunSummary{}.*m)>;
          if constexpr (std::is_same_v<T, double>) EXPECT_EQ(c, H5T_FLOAT) << name;
          else if constexpr (std::is_same_v<T, long> || std::is_same_v<T, bool>) EXPECT_EQ(c, H5T_INTEGER) << name;
          else {
            EXPECT_EQ(c, H5T_STRING) << name;
            EXPECT_TRUE(utf8) << name << " is not a variable-length UTF-8 string";
          }
        },
        e.member);
  }
  Id g(H5Gopen2(f_, "/summary", H5P_DEFAULT));
  ASSERT_TRUE(g.ok());
  std::size_t count = 0;
  H5Aiterate2(
      g, H5_INDEX_NAME, H5_ITER_NATIVE, nullptr,
      [](hid_t, const char*, const H5A_info_t*, void* n) -> herr_t {
        ++*static_cast<std::size_t*>(n);
        return 0;
      },
      &count);
  // The table, its units, and beside each verified mean its statistical uncertainty (the run
  // is not verified: no numerical errors).
  std::size_t verified = 0;
  for (const SummaryField& e : summary_fields()) verified += e.verify.verified;
  EXPECT_EQ(count, summary_fields().size() + 1 + verified) << "attributes beyond the table, its units and uncertainties";
  for (const SummaryField& e : summary_fields()) {
    if (e.verify.verified) {
      EXPECT_EQ(attribute_class(f_, "/summary", (std::string(e.name) + "_uncertainty").c_str()), H5T_FLOAT) << e.name;
    }
  }
  EXPECT_EQ(attribute_class(f_, "/summary", "units", nullptr), H5T_STRING) << "the units";
}

// The layout the viewer reads is JSON that a parser reads back.
TEST_F(OutputLayoutTest, LayoutIsJson) {
  const nlohmann::json j = nlohmann::json::parse(string_attribute("/parameters", "layout"));
  EXPECT_EQ(j.at("links").get<int>(), kLinks);
  ASSERT_EQ(j.at("pulleys").size(), 2u);
  for (const auto& p : j.at("pulleys")) {
    EXPECT_EQ(p.at("centre").size(), 2u);
    EXPECT_GT(p.at("running_radius").get<double>(), 0.0);
  }
}

TEST_F(OutputLayoutTest, H5dumpReadsHeader) {
  if (!fs::exists("/usr/bin/h5dump")) GTEST_SKIP() << "no /usr/bin/h5dump";
  const std::string cmd = "/usr/bin/h5dump -H " + shell_quote(file_->string()) + " >" +
                          shell_quote((*dir_ / "h5dump.txt").string()) + " 2>&1";
  const int status = std::system(cmd.c_str());
  ASSERT_TRUE(status != -1 && WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0);
}

}  // namespace
}  // namespace cvt

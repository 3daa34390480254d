#include "engine/io/h5_writer.hpp"

#include <gtest/gtest.h>
#include <hdf5.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

// HDF5's checksum of metadata (Jenkins' lookup3), which libhdf5 exports but does not declare
// in its public headers: a test that edits a superblock must write its checksum again.
extern "C" std::uint32_t H5_checksum_metadata(const void* data, std::size_t len, std::uint32_t initval);

namespace cvt {
namespace {

namespace fs = std::filesystem;

class H5WriterTest : public ::testing::Test {
 protected:
  void SetUp() override {
    h5_silence_error_printing();
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::random_device rd;
    dir_ = fs::temp_directory_path() /
           ("cvt_h5_writer_" + std::string(info->name()) + "_" + std::to_string(rd()));
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  std::string file(const std::string& name) const { return (dir_ / name).string(); }

  fs::path dir_;
};

// Read-side helpers, with the raw HDF5 C API.
struct Reader {
  explicit Reader(const std::string& path)
      : id(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT)) {}
  ~Reader() {
    if (id >= 0) H5Fclose(id);
  }
  hid_t id;
};

std::vector<hsize_t> dims_of(hid_t file, const std::string& path,
                             std::vector<hsize_t>* max_dims = nullptr) {
  const hid_t d = H5Dopen2(file, path.c_str(), H5P_DEFAULT);
  EXPECT_GE(d, 0) << path;
  const hid_t s = H5Dget_space(d);
  const int rank = H5Sget_simple_extent_ndims(s);
  std::vector<hsize_t> dims(static_cast<std::size_t>(rank)), max(dims.size());
  H5Sget_simple_extent_dims(s, dims.data(), max.data());
  if (max_dims) *max_dims = max;
  H5Sclose(s);
  H5Dclose(d);
  return dims;
}

std::vector<double> read_all(hid_t file, const std::string& path) {
  const hid_t d = H5Dopen2(file, path.c_str(), H5P_DEFAULT);
  EXPECT_GE(d, 0) << path;
  const hid_t s = H5Dget_space(d);
  std::vector<double> out(static_cast<std::size_t>(H5Sget_simple_extent_npoints(s)));
  if (!out.empty()) {
    EXPECT_GE(H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.data()), 0);
  }
  H5Sclose(s);
  H5Dclose(d);
  return out;
}

std::string read_string_dataset(hid_t file, const std::string& path, H5T_cset_t* cset) {
  const hid_t d = H5Dopen2(file, path.c_str(), H5P_DEFAULT);
  EXPECT_GE(d, 0) << path;
  const hid_t ftype = H5Dget_type(d);
  *cset = H5Tget_cset(ftype);
  EXPECT_TRUE(H5Tis_variable_str(ftype) > 0);
  const hid_t mtype = H5Tcopy(H5T_C_S1);
  H5Tset_size(mtype, H5T_VARIABLE);
  H5Tset_cset(mtype, H5T_CSET_UTF8);
  char* data = nullptr;
  EXPECT_GE(H5Dread(d, mtype, H5S_ALL, H5S_ALL, H5P_DEFAULT, &data), 0);
  std::string out = data ? data : "";
  const hid_t s = H5Dget_space(d);
  H5Dvlen_reclaim(mtype, s, H5P_DEFAULT, &data);
  H5Sclose(s);
  H5Tclose(mtype);
  H5Tclose(ftype);
  H5Dclose(d);
  return out;
}

std::string read_string_attribute(hid_t file, const std::string& object, const std::string& name) {
  const hid_t a = H5Aopen_by_name(file, object.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT);
  EXPECT_GE(a, 0) << object << "@" << name;
  const hid_t ftype = H5Aget_type(a);
  EXPECT_EQ(H5Tget_cset(ftype), H5T_CSET_UTF8);
  const hid_t mtype = H5Tcopy(H5T_C_S1);
  H5Tset_size(mtype, H5T_VARIABLE);
  H5Tset_cset(mtype, H5T_CSET_UTF8);
  char* data = nullptr;
  EXPECT_GE(H5Aread(a, mtype, &data), 0);
  std::string out = data ? data : "";
  H5free_memory(data);
  H5Tclose(mtype);
  H5Tclose(ftype);
  H5Aclose(a);
  return out;
}

double scalar_value(int i) { return std::sin(0.01 * i) * 1e3 + i; }

TEST_F(H5WriterTest, ScalarSeriesRoundTrips) {
  const std::string path = file("scalar.h5");
  {
    H5File f = H5File::create(path);
    H5Series& s = f.series("/observables/input_speed/value", {});
    for (int i = 0; i < 1000; ++i) s.append(scalar_value(i));
    EXPECT_EQ(s.rows(), 1000u);
    f.close();
    f.close();  // idempotent
  }
  EXPECT_GT(H5Fis_hdf5(path.c_str()), 0);
  Reader r(path);
  ASSERT_GE(r.id, 0);
  std::vector<hsize_t> max;
  EXPECT_EQ(dims_of(r.id, "/observables/input_speed/value", &max), std::vector<hsize_t>{1000});
  EXPECT_EQ(max, std::vector<hsize_t>{H5S_UNLIMITED});
  const std::vector<double> v = read_all(r.id, "/observables/input_speed/value");
  ASSERT_EQ(v.size(), 1000u);
  for (int i = 0; i < 1000; ++i) EXPECT_EQ(v[i], scalar_value(i)) << i;
}

TEST_F(H5WriterTest, VectorAndTensorSeriesRoundTrip) {
  const std::string path = file("shapes.h5");
  const int t2 = 333, t53 = 77;
  {
    H5File f = H5File::create(path);
    H5Series& a = f.series("pair", {2}, 64);
    H5Series& b = f.series("/chain/positions", {5, 3}, 16);
    for (int t = 0; t < t2; ++t) {
      const double row[2] = {t * 1.5, -t / 7.0};
      a.append(row);
    }
    for (int t = 0; t < t53; ++t) {
      double row[15];
      for (int k = 0; k < 15; ++k) row[k] = t * 100.0 + k + 1.0 / 3.0;
      b.append(row);
    }
    EXPECT_EQ(a.rows(), static_cast<hsize_t>(t2));
    EXPECT_EQ(b.rows(), static_cast<hsize_t>(t53));
    EXPECT_EQ(b.row_size(), 15u);
  }  // destructor closes
  Reader r(path);
  ASSERT_GE(r.id, 0);
  std::vector<hsize_t> max;
  EXPECT_EQ(dims_of(r.id, "/pair", &max), (std::vector<hsize_t>{t2, 2}));
  EXPECT_EQ(max, (std::vector<hsize_t>{H5S_UNLIMITED, 2}));
  EXPECT_EQ(dims_of(r.id, "/chain/positions", &max), (std::vector<hsize_t>{t53, 5, 3}));
  EXPECT_EQ(max, (std::vector<hsize_t>{H5S_UNLIMITED, 5, 3}));
  const std::vector<double> a = read_all(r.id, "/pair");
  ASSERT_EQ(a.size(), 2u * t2);
  for (int t = 0; t < t2; ++t) {
    EXPECT_EQ(a[2 * t], t * 1.5);
    EXPECT_EQ(a[2 * t + 1], -t / 7.0);
  }
  const std::vector<double> b = read_all(r.id, "/chain/positions");
  ASSERT_EQ(b.size(), 15u * t53);
  for (int t = 0; t < t53; ++t)
    for (int k = 0; k < 15; ++k) EXPECT_EQ(b[15 * t + k], t * 100.0 + k + 1.0 / 3.0);
}

TEST_F(H5WriterTest, DatasetIsChunkedAndCompressed) {
  const std::string path = file("chunked.h5");
  {
    H5File f = H5File::create(path);
    H5Series& s = f.series("/x", {5, 3}, 32);
    double row[15] = {};
    for (int t = 0; t < 100; ++t) s.append(row);
  }
  Reader r(path);
  ASSERT_GE(r.id, 0);
  const hid_t d = H5Dopen2(r.id, "/x", H5P_DEFAULT);
  ASSERT_GE(d, 0);
  const hid_t dcpl = H5Dget_create_plist(d);
  EXPECT_EQ(H5Pget_layout(dcpl), H5D_CHUNKED);
  hsize_t chunk[3] = {};
  EXPECT_EQ(H5Pget_chunk(dcpl, 3, chunk), 3);
  EXPECT_EQ(chunk[0], 32u);
  EXPECT_EQ(chunk[1], 5u);
  EXPECT_EQ(chunk[2], 3u);
  const int n = H5Pget_nfilters(dcpl);
  EXPECT_GT(n, 0);
  bool deflate = false, shuffle = false;
  for (int i = 0; i < n; ++i) {
    unsigned flags = 0, values[4] = {};
    std::size_t nvalues = 4;
    char name[64];
    const H5Z_filter_t id = H5Pget_filter2(dcpl, static_cast<unsigned>(i), &flags, &nvalues,
                                           values, sizeof name, name, nullptr);
    if (id == H5Z_FILTER_DEFLATE) {
      deflate = true;
      ASSERT_GE(nvalues, 1u);
      EXPECT_EQ(values[0], 4u);
    }
    if (id == H5Z_FILTER_SHUFFLE) shuffle = true;
  }
  EXPECT_TRUE(deflate);
  EXPECT_TRUE(shuffle);
  H5Pclose(dcpl);
  H5Dclose(d);
}

TEST_F(H5WriterTest, AttributesAndStringsRoundTrip) {
  const std::string path = file("strings.h5");
  const std::string config = "[geometry]\ncentre_distance = 0.160  # a = 160 mm, Ω ≈ 1\n";
  {
    H5File f = H5File::create(path);
    H5Series& s = f.series("/observables/input_speed/value", {});
    s.append(1.0);
    f.set_string_attribute("/", "cvt_version", "0.1.0");
    f.set_string_attribute("/observables/input_speed", "description", "input pulley speed");
    f.set_string_attribute("/observables/input_speed/value", "units", "rad/s");
    f.set_string_attribute("/observables/input_speed/value", "units", "rad·s⁻¹");  // replaces
    f.set_string_attribute("/meta/new_group", "note", "");  // creates the group
    f.write_string("/config/toml", config);
    f.write_string("empty_text", "");
    f.write_vector("/chain/rest_lengths", {0.008, 0.0081, -1e-300, 1e300});
    f.write_vector("/chain/none", {});
    EXPECT_THROW(f.write_string("/config/toml", "again"), H5Error);
  }
  Reader r(path);
  ASSERT_GE(r.id, 0);
  EXPECT_EQ(read_string_attribute(r.id, "/", "cvt_version"), "0.1.0");
  EXPECT_EQ(read_string_attribute(r.id, "/observables/input_speed", "description"),
            "input pulley speed");
  EXPECT_EQ(read_string_attribute(r.id, "/observables/input_speed/value", "units"), "rad·s⁻¹");
  EXPECT_EQ(read_string_attribute(r.id, "/meta/new_group", "note"), "");
  H5T_cset_t cset = H5T_CSET_ASCII;
  EXPECT_EQ(read_string_dataset(r.id, "/config/toml", &cset), config);
  EXPECT_EQ(cset, H5T_CSET_UTF8);
  EXPECT_EQ(read_string_dataset(r.id, "/empty_text", &cset), "");
  EXPECT_EQ(dims_of(r.id, "/chain/rest_lengths"), std::vector<hsize_t>{4});
  EXPECT_EQ(read_all(r.id, "/chain/rest_lengths"),
            (std::vector<double>{0.008, 0.0081, -1e-300, 1e300}));
  EXPECT_EQ(dims_of(r.id, "/chain/none"), std::vector<hsize_t>{0});
}

TEST_F(H5WriterTest, EmptySeriesIsValidWithShapeZero) {
  const std::string path = file("empty.h5");
  {
    H5File f = H5File::create(path);
    H5Series& s = f.series("/observables/nothing", {});
    f.series("/observables/nothing_3d", {4, 3});
    EXPECT_EQ(s.rows(), 0u);
    f.flush();
    f.close();
  }
  EXPECT_GT(H5Fis_hdf5(path.c_str()), 0);
  Reader r(path);
  ASSERT_GE(r.id, 0);
  std::vector<hsize_t> max;
  EXPECT_EQ(dims_of(r.id, "/observables/nothing", &max), std::vector<hsize_t>{0});
  EXPECT_EQ(max, std::vector<hsize_t>{H5S_UNLIMITED});
  EXPECT_EQ(dims_of(r.id, "/observables/nothing_3d"), (std::vector<hsize_t>{0, 4, 3}));
  EXPECT_TRUE(read_all(r.id, "/observables/nothing").empty());
}

TEST_F(H5WriterTest, FlushWritesPartialChunkAndAppendingContinues) {
  const std::string path = file("flush.h5");
  {
    H5File f = H5File::create(path);
    H5Series& s = f.series("/v", {}, 8);
    int i = 0;
    for (; i < 5; ++i) s.append(scalar_value(i));
    f.flush();  // partial chunk on disk
    EXPECT_EQ(s.rows(), 5u);
    for (; i < 21; ++i) s.append(scalar_value(i));
    f.flush();
    f.flush();  // nothing buffered: no-op
    for (; i < 30; ++i) s.append(scalar_value(i));
    EXPECT_EQ(s.rows(), 30u);
  }
  Reader r(path);
  ASSERT_GE(r.id, 0);
  const std::vector<double> v = read_all(r.id, "/v");
  ASSERT_EQ(v.size(), 30u);
  for (int i = 0; i < 30; ++i) EXPECT_EQ(v[i], scalar_value(i)) << i;
}

TEST_F(H5WriterTest, SeriesLookupAndMisuseThrow) {
  const std::string path = file("misuse.h5");
  H5File f = H5File::create(path);
  H5Series& a = f.series("/a/b", {3});
  EXPECT_EQ(&f.series("a/b", {3}), &a);  // same series, leading '/' optional
  EXPECT_THROW(f.series("/a/b", {4}), H5Error);
  EXPECT_THROW(a.append(1.0), H5Error);  // rows have 3 values
  EXPECT_THROW(f.series("/zero", {0}), H5Error);
  EXPECT_THROW(f.series("/nochunk", {}, 0), H5Error);
  try {
    f.series("/a/b/c", {});  // "/a/b" is a dataset, not a group
    ADD_FAILURE() << "expected H5Error";
  } catch (const H5Error& e) {
    EXPECT_NE(std::string(e.what()).find("/a/b/c"), std::string::npos) << e.what();
  }

  // Moving the file keeps the series references valid.
  H5File g = std::move(f);
  const double row[3] = {1, 2, 3};
  a.append(row);
  g.close();
  EXPECT_THROW(a.append(row), H5Error);  // series closed with the file
  EXPECT_THROW(g.flush(), H5Error);
  EXPECT_THROW(g.write_vector("/v", {1.0}), H5Error);

  Reader r(path);
  ASSERT_GE(r.id, 0);
  EXPECT_EQ(read_all(r.id, "/a/b"), (std::vector<double>{1, 2, 3}));
}

TEST_F(H5WriterTest, CreateInMissingDirectoryThrowsWithPath) {
  const std::string path = file("no/such/dir/out.h5");
  try {
    H5File::create(path);
    ADD_FAILURE() << "expected H5Error";
  } catch (const H5Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("H5Fcreate"), std::string::npos) << what;
    EXPECT_NE(what.find(path), std::string::npos) << what;
  }
}

// A writer killed in SWMR mode in the middle of a flush can leave index blocks on the disk
// that lie past the end of allocation its superblock records: the library then refuses to
// extend the dataset ("addr overflow"). The same state, made here by lowering a closed
// file's recorded end: open() with clear_status raises the end to the file's end, as
// h5clear -i does, and the series continues.
TEST_F(H5WriterTest, OpeningAKilledWritersFileReachesBlocksPastItsRecordedEnd) {
  const std::string path = file("killed.h5");
  {
    H5File f = H5File::create(path);
    H5Series& s = f.series("/v", {}, 8);
    for (int i = 0; i < 100; ++i) s.append(scalar_value(i));
  }
  const auto size = fs::file_size(path);
  // The recorded end is lowered to just inside the last chunk but one, which then straddles it
  // (as the index block did that a killed run left: addr overflow, addr = 704063, size = 803,
  // eoa = 704414).
  haddr_t straddling = HADDR_UNDEF;
  {
    Reader r(path);
    const hid_t d = H5Dopen2(r.id, "/v", H5P_DEFAULT);
    hsize_t chunks = 0, offset[1] = {0}, bytes = 0;
    unsigned mask = 0;
    const hid_t space = H5Dget_space(d);
    ASSERT_GE(H5Dget_num_chunks(d, space, &chunks), 0);
    ASSERT_EQ(chunks, 13u);
    ASSERT_GE(H5Dget_chunk_info(d, space, chunks - 2, offset, &mask, &straddling, &bytes), 0);
    H5Sclose(space);
    H5Dclose(d);
  }
  // Superblock version 3: the end-of-file address at bytes 28-35, the checksum of bytes
  // 0-43 at 44-47 (little-endian).
  std::string bytes;
  {
    std::ifstream in(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  ASSERT_EQ(bytes.size(), size);
  ASSERT_EQ(static_cast<unsigned char>(bytes[8]), 3u);
  std::uint64_t recorded = 0;
  std::memcpy(&recorded, bytes.data() + 28, 8);
  ASSERT_EQ(recorded, size);
  const std::uint64_t lowered = straddling + 1;
  ASSERT_LT(lowered, size);
  std::memcpy(bytes.data() + 28, &lowered, 8);
  const std::uint32_t sum = H5_checksum_metadata(bytes.data(), 44, 0);
  std::memcpy(bytes.data() + 44, &sum, 4);
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out << bytes;
  }
  const auto continue_it = [&](bool clear_status) {
    H5File f = H5File::open(path, clear_status);
    H5Series& s = f.series("/v", {}, 8);
    EXPECT_EQ(s.rows(), 100u);
    s.truncate(50);
    for (int i = 50; i < 120; ++i) s.append(scalar_value(i));
    f.close();
  };
  try {
    continue_it(false);
    ADD_FAILURE() << "a block past the recorded end was reached without raising it: the case is not tested";
  } catch (const H5Error& e) {
    EXPECT_NE(std::string(e.what()).find("addr overflow"), std::string::npos) << e.what();
  }
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out << bytes;
  }
  ASSERT_NO_THROW(continue_it(true));
  Reader r(path);
  ASSERT_GE(r.id, 0);
  const std::vector<double> v = read_all(r.id, "/v");
  ASSERT_EQ(v.size(), 120u);
  for (int i = 0; i < 120; ++i) EXPECT_EQ(v[i], scalar_value(i)) << i;
}

TEST_F(H5WriterTest, UsesLatestFileFormat) {
  const std::string path = file("latest.h5");
  H5File::create(path).close();
  Reader r(path);
  ASSERT_GE(r.id, 0);
  H5F_info2_t info;
  ASSERT_GE(H5Fget_info2(r.id, &info), 0);
  EXPECT_GE(info.super.version, 3u);  // superblock v3 (latest format) is what SWMR requires
}

TEST_F(H5WriterTest, H5dumpCanOpenFile) {
  if (!fs::exists("/usr/bin/h5dump")) GTEST_SKIP() << "h5dump not installed";
  const std::string path = file("dump.h5");
  {
    H5File f = H5File::create(path);
    H5Series& s = f.series("/observables/input_speed/value", {});
    for (int i = 0; i < 300; ++i) s.append(scalar_value(i));
    H5Series& p = f.series("/chain/positions", {5, 3});
    f.set_string_attribute("/observables/input_speed/value", "units", "rad/s");
    f.write_string("/config/toml", "a = 1\n");
    f.write_vector("/chain/pitch", {0.008});
    (void)p;
  }
  const std::string cmd = "/usr/bin/h5dump -H '" + path + "' > /dev/null 2>&1";
  EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
}

}  // namespace
}  // namespace cvt

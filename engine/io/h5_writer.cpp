#include "engine/io/h5_writer.hpp"

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <cstdio>
#include <cstring>
#include <exception>
#include <limits>
#include <mutex>
#include <utility>

namespace cvt {
namespace {

// HDF5's description of the innermost error on the default stack (call right after the failing
// call, before any other HDF5 call clears the stack).
std::string hdf5_error_detail() {
  std::string detail;
  auto walk = [](unsigned n, const H5E_error2_t* err, void* client) -> herr_t {
    auto* out = static_cast<std::string*>(client);
    if (n != 0 || err == nullptr) return 0;
    if (err->desc != nullptr && err->desc[0] != '\0') *out = err->desc;
    // A failed write or read: "file write failed: time = ..., error message = 'No space
    // left on device', ..." said as "file write failed: No space left on device".
    const std::size_t says = out->find("error message = '");
    if (says != std::string::npos) {
      const std::size_t from = says + 17, to = out->find('\'', from);
      *out = out->substr(0, out->find(':')) + ": " + out->substr(from, to == std::string::npos ? to : to - from);
    }
    char minor[256];
    if (H5Eget_msg(err->min_num, nullptr, minor, sizeof minor) > 0) {
      *out += out->empty() ? minor : std::string(" (") + minor + ")";
    }
    return 0;
  };
  if (H5Ewalk2(H5E_DEFAULT, H5E_WALK_UPWARD, walk, &detail) < 0) detail.clear();
  H5Eclear2(H5E_DEFAULT);
  return detail;
}

[[noreturn]] void fail(const std::string& operation, const std::string& path) {
  std::string message = "HDF5: " + operation + " failed for '" + path + "'";
  const std::string detail = hdf5_error_detail();
  if (!detail.empty()) message += ": " + detail;
  throw H5Error(message);
}

void check(herr_t status, const char* operation, const std::string& path) {
  if (status < 0) fail(operation, path);
}

herr_t close_id(hid_t id) {
  switch (H5Iget_type(id)) {
    case H5I_FILE: return H5Fclose(id);
    case H5I_GROUP: return H5Gclose(id);
    case H5I_DATASET: return H5Dclose(id);
    case H5I_DATASPACE: return H5Sclose(id);
    case H5I_DATATYPE: return H5Tclose(id);
    case H5I_ATTR: return H5Aclose(id);
    case H5I_GENPROP_LST: return H5Pclose(id);
    case H5I_BADID: return -1;
    default: return H5Idec_ref(id) < 0 ? -1 : 0;
  }
}

// "a/b" and "/a/b/" -> "/a/b"; "" and "/" -> "/".
std::string normalize(const std::string& path) {
  std::string out = (path.empty() || path.front() != '/') ? "/" + path : path;
  while (out.size() > 1 && out.back() == '/') out.pop_back();
  return out;
}

// Link creation property list: create missing intermediate groups, UTF-8 link names.
H5Handle make_lcpl(const std::string& path) {
  H5Handle lcpl(H5Pcreate(H5P_LINK_CREATE), "H5Pcreate(H5P_LINK_CREATE)", path);
  check(H5Pset_create_intermediate_group(lcpl.get(), 1), "H5Pset_create_intermediate_group",
        path);
  check(H5Pset_char_encoding(lcpl.get(), H5T_CSET_UTF8), "H5Pset_char_encoding", path);
  return lcpl;
}

// Scalar variable-length UTF-8 string type.
H5Handle make_string_type(const std::string& path) {
  H5Handle type(H5Tcopy(H5T_C_S1), "H5Tcopy(H5T_C_S1)", path);
  check(H5Tset_size(type.get(), H5T_VARIABLE), "H5Tset_size(H5T_VARIABLE)", path);
  check(H5Tset_cset(type.get(), H5T_CSET_UTF8), "H5Tset_cset(UTF8)", path);
  return type;
}

void require_no_nul(const std::string& text, const std::string& path) {
  if (text.find('\0') != std::string::npos) {
    throw H5Error("HDF5: string for '" + path + "' contains a NUL character");
  }
}

}  // namespace

void h5_silence_error_printing() {
  // Per thread: a thread-safe HDF5 keeps the error-printing setting per thread (runs in
  // several threads of one process, the Python module).
  thread_local bool done = false;
  if (!done) H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr), done = true;
}

// ---------------------------------------------------------------------------------------------
// H5Handle

H5Handle::H5Handle(hid_t id, const char* operation, const std::string& path) : id_(id) {
  if (id < 0) fail(operation, path);
}

H5Handle& H5Handle::operator=(H5Handle&& other) noexcept {
  if (this != &other) {
    reset();
    id_ = other.release();
  }
  return *this;
}

hid_t H5Handle::release() noexcept { return std::exchange(id_, H5I_INVALID_HID); }

void H5Handle::reset() noexcept {
  if (id_ >= 0) {
    if (close_id(id_) < 0) H5Eclear2(H5E_DEFAULT);
    id_ = H5I_INVALID_HID;
  }
}

void H5Handle::close(const std::string& path) {
  if (id_ < 0) return;
  const hid_t id = release();
  check(close_id(id), "close", path);
}

// ---------------------------------------------------------------------------------------------
// H5Series

H5Series::H5Series(hid_t file, std::string path, std::vector<hsize_t> row_shape,
                   hsize_t chunk_rows, bool integer)
    : path_(std::move(path)), row_shape_(std::move(row_shape)), chunk_rows_(chunk_rows) {
  if (chunk_rows_ == 0) throw H5Error("HDF5: chunk_rows must be > 0 for '" + path_ + "'");
  row_size_ = 1;
  for (hsize_t d : row_shape_) {
    if (d == 0) throw H5Error("HDF5: row_shape has a zero dimension for '" + path_ + "'");
    row_size_ *= d;
  }
  // HDF5 limits a chunk to 4 GiB.
  constexpr hsize_t kMaxChunkBytes = 0xFFFFFFFFull;
  if (row_size_ > kMaxChunkBytes / sizeof(double) / chunk_rows_) {
    throw H5Error("HDF5: chunk of " + std::to_string(chunk_rows_) + " rows exceeds 4 GiB for '" +
                  path_ + "'");
  }

  const int rank = static_cast<int>(row_shape_.size()) + 1;
  if (H5Lexists(file, path_.c_str(), H5P_DEFAULT) > 0) {
    // An existing series (a run's own file, continued): appends go after its last row.
    dataset_ = H5Handle(H5Dopen2(file, path_.c_str(), H5P_DEFAULT), "H5Dopen2", path_);
    H5Handle space(H5Dget_space(dataset_.get()), "H5Dget_space", path_);
    std::vector<hsize_t> dims(static_cast<std::size_t>(rank));
    if (H5Sget_simple_extent_ndims(space.get()) != rank) throw H5Error("HDF5: series '" + path_ + "' has another rank");
    H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
    if (!std::equal(row_shape_.begin(), row_shape_.end(), dims.begin() + 1))
      throw H5Error("HDF5: series '" + path_ + "' exists with another row shape");
    rows_written_ = dims[0];
    buffer_.reserve(static_cast<std::size_t>(chunk_rows_ * row_size_));
    return;
  }
  std::vector<hsize_t> dims{0}, max_dims{H5S_UNLIMITED}, chunk{chunk_rows_};
  for (hsize_t d : row_shape_) {
    dims.push_back(d);
    max_dims.push_back(d);
    chunk.push_back(d);
  }
  H5Handle space(H5Screate_simple(rank, dims.data(), max_dims.data()), "H5Screate_simple", path_);
  H5Handle dcpl(H5Pcreate(H5P_DATASET_CREATE), "H5Pcreate(H5P_DATASET_CREATE)", path_);
  check(H5Pset_chunk(dcpl.get(), rank, chunk.data()), "H5Pset_chunk", path_);
  check(H5Pset_shuffle(dcpl.get()), "H5Pset_shuffle", path_);
  check(H5Pset_deflate(dcpl.get(), 4), "H5Pset_deflate", path_);
  H5Handle lcpl = make_lcpl(path_);
  dataset_ = H5Handle(H5Dcreate2(file, path_.c_str(), integer ? H5T_STD_I64LE : H5T_IEEE_F64LE, space.get(),
                                 lcpl.get(), dcpl.get(), H5P_DEFAULT),
                      "H5Dcreate2", path_);
  buffer_.reserve(static_cast<std::size_t>(chunk_rows_ * row_size_));
}

H5Series::~H5Series() = default;

void H5Series::append(const double* row) {
  if (!dataset_) throw H5Error("HDF5: append to closed series '" + path_ + "'");
  buffer_.insert(buffer_.end(), row, row + row_size_);
  // Write whole chunks, aligned on chunk boundaries (a flush() may have left a partial one).
  if (rows() % chunk_rows_ == 0) write_buffer();
}

void H5Series::append(double value) {
  if (!row_shape_.empty()) {
    throw H5Error("HDF5: append(double) on series '" + path_ + "' whose rows have " +
                  std::to_string(row_size_) + " values");
  }
  append(&value);
}

void H5Series::write_buffer() {
  const hsize_t n = buffered_rows();
  if (n == 0) return;
  const int rank = static_cast<int>(row_shape_.size()) + 1;
  std::vector<hsize_t> extent{rows_written_ + n}, start{rows_written_}, count{n};
  for (hsize_t d : row_shape_) {
    extent.push_back(d);
    start.push_back(0);
    count.push_back(d);
  }
  check(H5Dset_extent(dataset_.get(), extent.data()), "H5Dset_extent", path_);
  H5Handle file_space(H5Dget_space(dataset_.get()), "H5Dget_space", path_);
  check(H5Sselect_hyperslab(file_space.get(), H5S_SELECT_SET, start.data(), nullptr,
                            count.data(), nullptr),
        "H5Sselect_hyperslab", path_);
  H5Handle mem_space(H5Screate_simple(rank, count.data(), nullptr), "H5Screate_simple", path_);
  check(H5Dwrite(dataset_.get(), H5T_NATIVE_DOUBLE, mem_space.get(), file_space.get(),
                 H5P_DEFAULT, buffer_.data()),
        "H5Dwrite", path_);
  rows_written_ += n;
  buffer_.clear();
}

void H5Series::truncate(hsize_t rows) {
  if (!dataset_) throw H5Error("HDF5: truncate of closed series '" + path_ + "'");
  write_buffer();
  if (rows >= rows_written_) return;
  std::vector<hsize_t> extent{rows};
  for (hsize_t d : row_shape_) extent.push_back(d);
  check(H5Dset_extent(dataset_.get(), extent.data()), "H5Dset_extent", path_);
  rows_written_ = rows;
}

void H5Series::flush() {
  if (dataset_) write_buffer();
}

void H5Series::close() {
  if (!dataset_) return;
  try {
    write_buffer();
  } catch (...) {
    dataset_.reset();
    buffer_.clear();
    throw;
  }
  dataset_.close(path_);
}

// ---------------------------------------------------------------------------------------------
// H5File

H5File::H5File(H5Handle file, std::string path) : file_(std::move(file)), path_(std::move(path)) {}

H5File H5File::create(const std::string& path) {
  h5_silence_error_printing();
  H5Handle fapl(H5Pcreate(H5P_FILE_ACCESS), "H5Pcreate(H5P_FILE_ACCESS)", path);
  check(H5Pset_libver_bounds(fapl.get(), H5F_LIBVER_LATEST, H5F_LIBVER_LATEST),
        "H5Pset_libver_bounds", path);
  H5Handle file(H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, fapl.get()), "H5Fcreate",
                path);
  return H5File(std::move(file), path);
}

H5File H5File::create_in_memory(const std::string& name) {
  h5_silence_error_printing();
  H5Handle fapl(H5Pcreate(H5P_FILE_ACCESS), "H5Pcreate(H5P_FILE_ACCESS)", name);
  check(H5Pset_fapl_core(fapl.get(), 64 * 1024, 0), "H5Pset_fapl_core", name);
  // The default (earliest) format: HDF5 1.10's image of a file in the latest format carries a
  // superblock whose checksum does not match its cleared open-for-writing mark.
  H5Handle file(H5Fcreate(name.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, fapl.get()), "H5Fcreate", name);
  return H5File(std::move(file), name);
}

std::vector<unsigned char> H5File::image() {
  flush();
  const ssize_t n = H5Fget_file_image(file_.get(), nullptr, 0);
  if (n < 0) fail("H5Fget_file_image", path_);
  std::vector<unsigned char> bytes(static_cast<std::size_t>(n));
  if (H5Fget_file_image(file_.get(), bytes.data(), bytes.size()) != n) fail("H5Fget_file_image", path_);
  return bytes;
}

long long extend_to_recorded_end(const std::string& path) {
  // Superblock version 2 or 3: signature (8 bytes), version, size of offsets, size of
  // lengths, flags, then four addresses (base, extension, end of file, root group).
  unsigned char sb[48] = {};
  std::FILE* in = std::fopen(path.c_str(), "rb");
  if (!in) return -1;
  const std::size_t got = std::fread(sb, 1, sizeof sb, in);
  std::fclose(in);
  static const unsigned char kSignature[8] = {0x89, 'H', 'D', 'F', '\r', '\n', 0x1a, '\n'};
  if (got < 36 || std::memcmp(sb, kSignature, 8) != 0 || sb[8] < 2 || sb[9] != 8) return -1;
  std::uint64_t base = 0, end = 0;
  for (int i = 7; i >= 0; --i) base = base << 8 | sb[12 + i], end = end << 8 | sb[28 + i];
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (ec || base != 0 || end <= size || end - size > (std::uint64_t{1} << 32)) return -1;
  std::filesystem::resize_file(path, end, ec);
  return ec ? -1 : static_cast<long long>(size);
}

H5File H5File::open(const std::string& path, bool clear_status) {
  h5_silence_error_printing();
  H5Handle fapl(H5Pcreate(H5P_FILE_ACCESS), "H5Pcreate(H5P_FILE_ACCESS)", path);
  check(H5Pset_libver_bounds(fapl.get(), H5F_LIBVER_LATEST, H5F_LIBVER_LATEST),
        "H5Pset_libver_bounds", path);
  // The library's own switch for h5clear -s (a file-access property it registers but does
  // not declare in its public headers).
  static const char* const kClearStatus = "clear_status_flags";
  if (clear_status) {
    hbool_t clear = true;
    if (H5Pexist(fapl.get(), kClearStatus) <= 0)
      throw H5Error("HDF5: this library cannot clear the open-for-writing mark of '" + path + "': h5clear -s " + path);
    check(H5Pset(fapl.get(), kClearStatus, &clear), "H5Pset(clear_status_flags)", path);
  }
  H5Handle file(H5Fopen(path.c_str(), H5F_ACC_RDWR, fapl.get()), "H5Fopen", path);
  if (clear_status) check(H5Fincrement_filesize(file.get(), 0), "H5Fincrement_filesize", path);
  return H5File(std::move(file), path);
}

H5File H5File::open_for_reading(const std::string& path, bool* marked) {
  h5_silence_error_printing();
  hid_t f = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const bool swmr = f < 0;
  if (swmr) {
    H5Eclear2(H5E_DEFAULT);
    f = H5Fopen(path.c_str(), H5F_ACC_RDONLY | H5F_ACC_SWMR_READ, H5P_DEFAULT);
  }
  if (marked) *marked = swmr;
  return H5File(H5Handle(f, "H5Fopen", path), path);
}

void H5File::start_swmr() {
  require_open("H5Fstart_swmr_write", path_);
  flush();
  check(H5Fstart_swmr_write(file_.get()), "H5Fstart_swmr_write", path_);
}

H5File& H5File::operator=(H5File&& other) noexcept {
  if (this != &other) {
    try {
      close();
    } catch (...) {
    }
    file_ = std::move(other.file_);
    path_ = std::move(other.path_);
    series_ = std::move(other.series_);
  }
  return *this;
}

H5File::~H5File() {
  try {
    close();
  } catch (...) {
  }
}

void H5File::require_open(const char* operation, const std::string& object_path) const {
  if (!file_) {
    throw H5Error(std::string("HDF5: ") + operation + " on closed file '" + path_ + "' for '" +
                  object_path + "'");
  }
}

bool H5File::link_exists(const std::string& object_path) const {
  // H5Lexists needs every intermediate link to exist: walk the path one component at a time.
  for (std::size_t pos = 1;; ++pos) {
    pos = object_path.find('/', pos);
    const std::string prefix = object_path.substr(0, pos);  // the whole path when npos
    if (prefix.size() > 1) {
      const htri_t exists = H5Lexists(file_.get(), prefix.c_str(), H5P_DEFAULT);
      if (exists < 0) fail("H5Lexists", prefix);
      if (exists == 0) return false;
    }
    if (pos == std::string::npos) return true;
  }
}

H5Series& H5File::series(const std::string& path, std::vector<hsize_t> row_shape,
                         hsize_t chunk_rows, bool integer) {
  const std::string key = normalize(path);
  require_open("series", key);
  auto it = series_.find(key);
  if (it != series_.end()) {
    if (it->second->row_shape() != row_shape) {
      throw H5Error("HDF5: series '" + key + "' already exists with a different row shape");
    }
    return *it->second;
  }
  std::unique_ptr<H5Series> created(
      new H5Series(file_.get(), key, std::move(row_shape), chunk_rows, integer));
  return *series_.emplace(key, std::move(created)).first->second;
}

H5Handle H5File::attribute_owner(const std::string& path, const std::string& name, const std::string& where) {
  if (!link_exists(path)) {
    H5Handle lcpl = make_lcpl(path);
    H5Handle group(H5Gcreate2(file_.get(), path.c_str(), lcpl.get(), H5P_DEFAULT, H5P_DEFAULT),
                   "H5Gcreate2", path);
    group.close(path);
  }
  H5Handle object(H5Oopen(file_.get(), path.c_str(), H5P_DEFAULT), "H5Oopen", path);
  const htri_t exists = H5Aexists(object.get(), name.c_str());
  if (exists < 0) fail("H5Aexists", where);
  if (exists > 0) check(H5Adelete(object.get(), name.c_str()), "H5Adelete", where);
  return object;
}

void H5File::set_string_attribute(const std::string& object_path, const std::string& name,
                                  const std::string& value) {
  const std::string path = normalize(object_path);
  const std::string where = path + "@" + name;
  require_open("set_string_attribute", where);
  require_no_nul(value, where);
  H5Handle object = attribute_owner(path, name, where);
  H5Handle type = make_string_type(where);
  H5Handle space(H5Screate(H5S_SCALAR), "H5Screate(H5S_SCALAR)", where);
  H5Handle acpl(H5Pcreate(H5P_ATTRIBUTE_CREATE), "H5Pcreate(H5P_ATTRIBUTE_CREATE)", where);
  check(H5Pset_char_encoding(acpl.get(), H5T_CSET_UTF8), "H5Pset_char_encoding", where);
  H5Handle attr(H5Acreate2(object.get(), name.c_str(), type.get(), space.get(), acpl.get(),
                           H5P_DEFAULT),
                "H5Acreate2", where);
  const char* data = value.c_str();
  check(H5Awrite(attr.get(), type.get(), &data), "H5Awrite", where);
  attr.close(where);
  object.close(path);
}

void H5File::set_double_attribute(const std::string& object_path, const std::string& name, double value) {
  const std::string path = normalize(object_path);
  const std::string where = path + "@" + name;
  require_open("set_double_attribute", where);
  H5Handle object = attribute_owner(path, name, where);
  H5Handle space(H5Screate(H5S_SCALAR), "H5Screate(H5S_SCALAR)", where);
  H5Handle attr(H5Acreate2(object.get(), name.c_str(), H5T_IEEE_F64LE, space.get(), H5P_DEFAULT,
                           H5P_DEFAULT),
                "H5Acreate2", where);
  check(H5Awrite(attr.get(), H5T_NATIVE_DOUBLE, &value), "H5Awrite", where);
  attr.close(where);
  object.close(path);
}

void H5File::set_strings_attribute(const std::string& object_path, const std::string& name,
                                   const std::vector<std::string>& v) {
  const std::string path = normalize(object_path);
  const std::string where = path + "@" + name;
  require_open("set_strings_attribute", where);
  std::vector<const char*> data;
  for (const std::string& x : v) {
    require_no_nul(x, where);
    data.push_back(x.c_str());
  }
  H5Handle object = attribute_owner(path, name, where);
  H5Handle type = make_string_type(where);
  const hsize_t n = v.size();
  H5Handle space(H5Screate_simple(1, &n, nullptr), "H5Screate_simple", where);
  H5Handle acpl(H5Pcreate(H5P_ATTRIBUTE_CREATE), "H5Pcreate(H5P_ATTRIBUTE_CREATE)", where);
  check(H5Pset_char_encoding(acpl.get(), H5T_CSET_UTF8), "H5Pset_char_encoding", where);
  H5Handle attr(H5Acreate2(object.get(), name.c_str(), type.get(), space.get(), acpl.get(), H5P_DEFAULT),
                "H5Acreate2", where);
  if (n > 0) check(H5Awrite(attr.get(), type.get(), data.data()), "H5Awrite", where);
  attr.close(where);
  object.close(path);
}

void H5File::set_int_attribute(const std::string& object_path, const std::string& name, long long value) {
  const std::string path = normalize(object_path);
  const std::string where = path + "@" + name;
  require_open("set_int_attribute", where);
  H5Handle object = attribute_owner(path, name, where);
  H5Handle space(H5Screate(H5S_SCALAR), "H5Screate(H5S_SCALAR)", where);
  H5Handle attr(H5Acreate2(object.get(), name.c_str(), H5T_STD_I64LE, space.get(), H5P_DEFAULT, H5P_DEFAULT),
                "H5Acreate2", where);
  check(H5Awrite(attr.get(), H5T_NATIVE_LLONG, &value), "H5Awrite", where);
  attr.close(where);
  object.close(path);
}

void H5File::set_ints_attribute(const std::string& object_path, const std::string& name,
                                const std::vector<long long>& v) {
  const std::string path = normalize(object_path);
  const std::string where = path + "@" + name;
  require_open("set_ints_attribute", where);
  H5Handle object = attribute_owner(path, name, where);
  const hsize_t n = v.size();
  H5Handle space(H5Screate_simple(1, &n, nullptr), "H5Screate_simple", where);
  H5Handle attr(H5Acreate2(object.get(), name.c_str(), H5T_STD_I64LE, space.get(), H5P_DEFAULT, H5P_DEFAULT),
                "H5Acreate2", where);
  check(H5Awrite(attr.get(), H5T_NATIVE_LLONG, v.data()), "H5Awrite", where);
  attr.close(where);
  object.close(path);
}

void H5File::write_strings(const std::string& dataset_path, const std::vector<std::string>& v) {
  const std::string path = normalize(dataset_path);
  require_open("write_strings", path);
  if (link_exists(path)) throw H5Error("HDF5: dataset '" + path + "' already exists");
  std::vector<const char*> data;
  for (const std::string& x : v) {
    require_no_nul(x, path);
    data.push_back(x.c_str());
  }
  H5Handle type = make_string_type(path);
  const hsize_t dims[1] = {static_cast<hsize_t>(v.size())};
  H5Handle space(H5Screate_simple(1, dims, nullptr), "H5Screate_simple", path);
  H5Handle lcpl = make_lcpl(path);
  H5Handle dataset(H5Dcreate2(file_.get(), path.c_str(), type.get(), space.get(), lcpl.get(),
                              H5P_DEFAULT, H5P_DEFAULT),
                   "H5Dcreate2", path);
  if (!v.empty())
    check(H5Dwrite(dataset.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, data.data()), "H5Dwrite", path);
  dataset.close(path);
}

void H5File::write_string(const std::string& dataset_path, const std::string& text) {
  const std::string path = normalize(dataset_path);
  require_open("write_string", path);
  require_no_nul(text, path);
  if (link_exists(path)) throw H5Error("HDF5: dataset '" + path + "' already exists");
  H5Handle type = make_string_type(path);
  H5Handle space(H5Screate(H5S_SCALAR), "H5Screate(H5S_SCALAR)", path);
  H5Handle lcpl = make_lcpl(path);
  H5Handle dataset(H5Dcreate2(file_.get(), path.c_str(), type.get(), space.get(), lcpl.get(),
                              H5P_DEFAULT, H5P_DEFAULT),
                   "H5Dcreate2", path);
  const char* data = text.c_str();
  check(H5Dwrite(dataset.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, &data), "H5Dwrite",
        path);
  dataset.close(path);
}

void H5File::write_vector(const std::string& dataset_path, const std::vector<double>& v) {
  const std::string path = normalize(dataset_path);
  require_open("write_vector", path);
  if (link_exists(path)) throw H5Error("HDF5: dataset '" + path + "' already exists");
  const hsize_t dims[1] = {static_cast<hsize_t>(v.size())};
  H5Handle space(H5Screate_simple(1, dims, nullptr), "H5Screate_simple", path);
  H5Handle lcpl = make_lcpl(path);
  H5Handle dataset(H5Dcreate2(file_.get(), path.c_str(), H5T_IEEE_F64LE, space.get(), lcpl.get(),
                              H5P_DEFAULT, H5P_DEFAULT),
                   "H5Dcreate2", path);
  if (!v.empty()) {
    check(H5Dwrite(dataset.get(), H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data()),
          "H5Dwrite", path);
  }
  dataset.close(path);
}

void H5File::flush() {
  require_open("flush", path_);
  for (auto& [key, s] : series_) s->flush();
  check(H5Fflush(file_.get(), H5F_SCOPE_GLOBAL), "H5Fflush", path_);
}

void H5File::close() {
  std::exception_ptr first;
  for (auto& [key, s] : series_) {
    try {
      s->close();
    } catch (...) {
      if (!first) first = std::current_exception();
    }
  }
  try {
    file_.close(path_);
  } catch (...) {
    if (!first) first = std::current_exception();
  }
  if (first) std::rethrow_exception(first);
}

bool H5File::exists(const std::string& object_path) const {
  return is_open() && link_exists(normalize(object_path));
}

void H5File::remove(const std::string& object_path) {
  const std::string path = normalize(object_path);
  require_open("remove", path);
  if (link_exists(path)) check(H5Ldelete(file_.get(), path.c_str(), H5P_DEFAULT), "H5Ldelete", path);
}

std::vector<double> H5File::read_doubles(const std::string& dataset_path) const {
  const std::string path = normalize(dataset_path);
  require_open("read_doubles", path);
  H5Handle dataset(H5Dopen2(file_.get(), path.c_str(), H5P_DEFAULT), "H5Dopen2", path);
  H5Handle space(H5Dget_space(dataset.get()), "H5Dget_space", path);
  const hssize_t n = H5Sget_simple_extent_npoints(space.get());
  if (n < 0) fail("H5Sget_simple_extent_npoints", path);
  std::vector<double> v(static_cast<std::size_t>(n));
  if (n > 0)
    check(H5Dread(dataset.get(), H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data()), "H5Dread", path);
  return v;
}

std::string H5File::read_string(const std::string& dataset_path) const {
  const std::string path = normalize(dataset_path);
  require_open("read_string", path);
  H5Handle dataset(H5Dopen2(file_.get(), path.c_str(), H5P_DEFAULT), "H5Dopen2", path);
  H5Handle type = make_string_type(path);
  char* text = nullptr;
  check(H5Dread(dataset.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, &text), "H5Dread", path);
  std::string s = text ? text : "";
  H5free_memory(text);
  return s;
}

std::string H5File::read_string_attribute(const std::string& object_path, const std::string& name) const {
  const std::string path = normalize(object_path);
  const std::string where = path + "@" + name;
  require_open("read_string_attribute", where);
  H5Handle attr(H5Aopen_by_name(file_.get(), path.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT), "H5Aopen_by_name",
                where);
  H5Handle type = make_string_type(where);
  char* text = nullptr;
  check(H5Aread(attr.get(), type.get(), &text), "H5Aread", where);
  std::string s = text ? text : "";
  H5free_memory(text);
  return s;
}

}  // namespace cvt

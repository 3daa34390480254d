// Thin RAII wrapper over the HDF5 C API for writing simulation output.
//
// H5File owns the file and every H5Series created through it. A series is one extendible,
// chunked, shuffle+deflate(4) compressed double dataset whose first dimension grows by one row
// per append(). Rows are buffered in memory and written one chunk-aligned block at a time, so
// append() is amortised O(row size); flush() and close() write the partial block that is left.
//
// Every failing HDF5 call throws H5Error naming the operation, the path and HDF5's own
// description of the innermost error. HDF5's automatic error-stack printing is switched off.
//
// Not thread-safe: the serial HDF5 library must be used from one thread at a time.
#pragma once

#include <hdf5.h>

#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace cvt {

class H5Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Switches off HDF5's automatic printing of its error stack (once per process; the errors are
// reported through H5Error instead). Called by H5File::create(); idempotent.
void h5_silence_error_printing();
// A file in the latest format that ends before the end its superblock records (a write that
// failed on a full disk after the superblock was written): extended with zeros to that end,
// so that it opens and its rows up to the last flush can be kept. Returns the size it had
// (to undo with std::filesystem::resize_file), or -1 where nothing was done.
long long extend_to_recorded_end(const std::string& path);

// Owns an hid_t and closes it with the matching H5*close (chosen by H5Iget_type) on destruction.
// Movable, not copyable. Never wrap a library-owned id such as H5T_NATIVE_DOUBLE.
class H5Handle {
 public:
  H5Handle() noexcept = default;
  explicit H5Handle(hid_t id) noexcept : id_(id) {}
  // Takes ownership of `id`, throwing H5Error("<operation> failed for '<path>'") if id < 0.
  H5Handle(hid_t id, const char* operation, const std::string& path);
  ~H5Handle() { reset(); }

  H5Handle(const H5Handle&) = delete;
  H5Handle& operator=(const H5Handle&) = delete;
  H5Handle(H5Handle&& other) noexcept : id_(other.release()) {}
  H5Handle& operator=(H5Handle&& other) noexcept;

  hid_t get() const noexcept { return id_; }
  bool valid() const noexcept { return id_ >= 0; }
  explicit operator bool() const noexcept { return valid(); }

  // Gives up ownership without closing.
  hid_t release() noexcept;
  // Closes the held id (errors ignored) and becomes empty.
  void reset() noexcept;
  // Closes the held id and becomes empty; throws H5Error if HDF5 reports a failure.
  void close(const std::string& path = {});

 private:
  hid_t id_ = H5I_INVALID_HID;
};

class H5File;

// One extendible double dataset of shape [T] + row_shape. Created only by H5File::series().
class H5Series {
 public:
  H5Series(const H5Series&) = delete;
  H5Series& operator=(const H5Series&) = delete;
  ~H5Series();

  // Appends one row of row_size() = prod(row_shape) values.
  void append(const double* row);
  // Appends one value; only for an empty row_shape (a [T] series).
  void append(double value);

  // Rows appended so far (written and still buffered).
  hsize_t rows() const noexcept { return rows_written_ + buffered_rows(); }
  const std::string& path() const noexcept { return path_; }
  const std::vector<hsize_t>& row_shape() const noexcept { return row_shape_; }
  hsize_t row_size() const noexcept { return row_size_; }
  hsize_t chunk_rows() const noexcept { return chunk_rows_; }
  bool is_open() const noexcept { return dataset_.valid(); }

  // Writes the buffered rows to the file (no H5Fflush). H5File::flush() calls it.
  void flush();
  // Keeps the first `rows` rows and drops the rest (appends then continue after them).
  void truncate(hsize_t rows);
  // Flushes, then closes the dataset; idempotent. append() afterwards throws H5Error.
  void close();

 private:
  friend class H5File;
  H5Series(hid_t file, std::string path, std::vector<hsize_t> row_shape, hsize_t chunk_rows, bool integer);

  hsize_t buffered_rows() const noexcept {
    return static_cast<hsize_t>(buffer_.size()) / row_size_;
  }
  void write_buffer();

  H5Handle dataset_;
  std::string path_;
  std::vector<hsize_t> row_shape_;
  hsize_t row_size_ = 1;
  hsize_t chunk_rows_ = 0;
  hsize_t rows_written_ = 0;
  std::vector<double> buffer_;
};

class H5File {
 public:
  // Creates (truncates) the file, with the latest file format (libver bounds LATEST..LATEST)
  // so that SWMR writing can be enabled later.
  static H5File create(const std::string& path);
  // A file kept in memory only (the core driver without a backing store), named `name` in
  // messages, in the library's default format; image() gives its bytes, to be written by the
  // caller (a checkpoint: a disk that fills fails the caller's write, not the library's).
  static H5File create_in_memory(const std::string& name);
  std::vector<unsigned char> image();
  // Opens an existing file for reading and writing (not in SWMR mode): to add objects
  // after a SWMR run has closed it (the end-of-run /profile group).
  // clear_status: a file left marked as open for writing by a killed writer has that mark
  // cleared first, as h5clear -s does, and its end of allocation raised to its end of file, as
  // h5clear -i does: a writer killed in SWMR mode may have written blocks past the end its
  // superblock records, which the library would otherwise refuse to reach ("addr overflow")
  // or allocate over. Only for a file whose writer is known to be gone (its FileLock held by
  // the caller).
  static H5File open(const std::string& path, bool clear_status = false);
  // Opens an existing file read-only; nothing in it changes. One marked as open for writing
  // (a writer has it, or one was killed with kill -9 and left the mark h5clear -s clears)
  // opens as a SWMR reader, and *marked says so. Throws H5Error where it does not open.
  static H5File open_for_reading(const std::string& path, bool* marked = nullptr);

  H5File(H5File&& other) noexcept = default;
  H5File& operator=(H5File&& other) noexcept;
  H5File(const H5File&) = delete;
  H5File& operator=(const H5File&) = delete;
  ~H5File();

  // The series at `path` (a leading '/' is optional), created with its intermediate groups on
  // first use ("/observables/input_speed/value"); a dataset already in the file (opened with
  // open()) is continued: appends go after its rows. A later call with the same path returns the
  // same object and throws H5Error if row_shape differs. Every dimension of row_shape and
  // chunk_rows must be > 0. The reference stays valid for the lifetime of this H5File (after
  // close() the series is closed and append() throws).
  // integer: the dataset holds 64-bit integers (H5MD's `step`); rows are still appended as
  // doubles, which HDF5 converts (exactly, for integers below 2^53).
  H5Series& series(const std::string& path, std::vector<hsize_t> row_shape,
                   hsize_t chunk_rows = 256, bool integer = false);

  // A scalar variable-length UTF-8 string attribute on an existing group or dataset (object_path
  // "/" is the root group); a group that does not exist yet is created, with its parents.
  // Replaces an attribute of the same name.
  void set_string_attribute(const std::string& object_path, const std::string& name,
                            const std::string& value);
  // A 1-D attribute of variable-length UTF-8 strings (h5py reads its entries as str; a
  // string *dataset* it reads as bytes).
  void set_strings_attribute(const std::string& object_path, const std::string& name,
                             const std::vector<std::string>& v);
  // A scalar 64-bit integer attribute (same rules as set_string_attribute).
  void set_int_attribute(const std::string& object_path, const std::string& name, long long value);
  // A 1-D 64-bit integer attribute (H5MD's version [major, minor]).
  void set_ints_attribute(const std::string& object_path, const std::string& name, const std::vector<long long>& v);
  // A scalar double attribute (same rules as set_string_attribute).
  void set_double_attribute(const std::string& object_path, const std::string& name, double value);
  // A 1-D dataset of variable-length UTF-8 strings; creates intermediate groups.
  void write_strings(const std::string& dataset_path, const std::vector<std::string>& v);
  // A scalar variable-length UTF-8 string dataset; creates intermediate groups. The dataset must
  // not exist yet.
  void write_string(const std::string& dataset_path, const std::string& text);
  // A 1-D fixed-size (contiguous) double dataset of v.size() elements; creates intermediate
  // groups. The dataset must not exist yet.
  void write_vector(const std::string& dataset_path, const std::vector<double>& v);

  // Whether a group or dataset exists at object_path.
  bool exists(const std::string& object_path) const;
  // Unlinks a group or dataset (nothing if there is none): to rewrite it.
  void remove(const std::string& object_path);
  // A whole double dataset, flattened in row-major order.
  std::vector<double> read_doubles(const std::string& dataset_path) const;
  // A scalar string dataset, and a string attribute.
  std::string read_string(const std::string& dataset_path) const;
  std::string read_string_attribute(const std::string& object_path, const std::string& name) const;

  // Writes the buffered rows of every series, then H5Fflush(H5F_SCOPE_GLOBAL).
  void flush();
  // Switches to single-writer/multiple-reader mode (H5Fstart_swmr_write): readers may then
  // open the file with SWMR read access while it grows. Every dataset and attribute must
  // exist before: in SWMR mode only appends to existing datasets are allowed.
  void start_swmr();
  // Writes the buffered rows, closes every dataset and the file; idempotent; the destructor
  // calls it (and swallows errors: call close() yourself to see them).
  void close();

  bool is_open() const noexcept { return file_.valid(); }
  const std::string& path() const noexcept { return path_; }
  hid_t id() const noexcept { return file_.get(); }

 private:
  H5File(H5Handle file, std::string path);
  void require_open(const char* operation, const std::string& object_path) const;
  bool link_exists(const std::string& object_path) const;
  // The object at path (a group created if missing) with no attribute `name` left on it.
  H5Handle attribute_owner(const std::string& path, const std::string& name, const std::string& where);

  H5Handle file_;
  std::string path_;
  std::map<std::string, std::unique_ptr<H5Series>> series_;
};

}  // namespace cvt

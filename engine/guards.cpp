#include "engine/guards.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>

namespace cvt {

namespace {

// The shortest decimal that reads back as x ("3e-07", not "2.9999999999999999e-07").
std::string shortest(double x) {
  char b[64];
  for (int p = 1; p <= 17; ++p) {
    std::snprintf(b, sizeof b, "%.*g", p, x);
    if (std::strtod(b, nullptr) == x) break;
  }
  return b;
}

}  // namespace

bool divides(double h, double x) {
  const double k = std::round(x / h);
  return k >= 1 && std::abs(k * h - x) <= 1e-12 * x;
}

void check_step_grid(const Config& c) {
  if (adaptive_steps(c)) {
    // The run's grid is the sample interval; the steps in between are the driver's.
    for (const auto& [key, x] : {std::pair<const char*, double>{"run.snapshot_interval", c.run.snapshot_interval},
                                 std::pair<const char*, double>{"run.t_end", c.run.t_end}})
      if (x > 0 && !divides(c.run.sample_interval, x))
        throw ConfigError("run.sample_interval", shortest(c.run.sample_interval),
                          "does not divide " + std::string(key) + " = " + shortest(x) +
                              " s: with adaptive steps (integrator.tolerance > 0) the steps end on the sample times, "
                              "so run.t_end and run.snapshot_interval must be multiples of run.sample_interval");
    return;
  }
  const double h = c.integrator.step;
  const std::vector<std::pair<const char*, double>> keys = {{"run.sample_interval", c.run.sample_interval},
                                                            {"run.snapshot_interval", c.run.snapshot_interval},
                                                            {"run.t_end", c.run.t_end}};
  const auto all_divide = [&](double step) {
    for (const auto& [key, x] : keys)
      if (x > 0 && !divides(step, x)) return false;
    return true;
  };
  for (const auto& [key, x] : keys) {
    if (!(x > 0) || divides(h, x)) continue;
    // The largest step below h that divides all three: x / n for the smallest n that fits.
    const double base = std::min(c.run.sample_interval > 0 ? c.run.sample_interval : c.run.t_end, c.run.t_end);
    double fit = 0;
    // (Not below h / 2: a step of 1e-11 s that happens to divide them is no advice.)
    for (double n = std::ceil(base / h * (1 - 1e-12)); n < 1e6 && base / n >= 0.5 * h && fit == 0; ++n)
      if (all_divide(base / n)) fit = base / n;
    char steps[32];
    std::snprintf(steps, sizeof steps, "%.10g", x / h);
    std::string reason = "does not divide " + std::string(key) + " = " + shortest(x) + " s (" + steps +
                         " steps): samples would not fall on multiples of the step and the run would not end at "
                         "run.t_end; choose a step that divides run.t_end, run.sample_interval and "
                         "run.snapshot_interval";
    if (fit > 0) reason += ", e.g. --step " + shortest(fit);
    else reason += ", with run.t_end a multiple of run.sample_interval";
    throw ConfigError("integrator.step", shortest(h), reason);
  }
}

double energy_turnover(const Sample& s) {
  return std::abs(s.work_input) + std::abs(s.work_output) + std::abs(s.work_dissipated) + std::abs(s.work_clamping) +
         std::abs(s.work_contact_switching);
}

std::string EnergyGuard::check(const Sample& s) {
  const double turnover = energy_turnover(s);
  if (warned || !(turnover >= turnover_min)) return "";
  if (std::abs(s.energy_residual) <= limit * turnover && std::isfinite(s.energy_residual)) return "";
  warned = true;
  char b[512];
  std::snprintf(b, sizeof b,
                "at t = %.6g s the energy balance's residual is %.4g J, %.1f %% of the energy turned over (%.4g J; "
                "limit %.0f %%): the integration is not accurate, reduce integrator.step",
                s.t, s.energy_residual, 100 * std::abs(s.energy_residual) / turnover, turnover, 100 * limit);
  return b;
}

std::string rk4_stability_warning(double h, double rho, double t) {
  const double h_stable = rho > 0 && std::isfinite(rho) ? 2.8 / rho : 0;
  if (!(h_stable > 0) || h <= h_stable) return "";
  char b[512];
  std::snprintf(b, sizeof b,
                "RK4's step %.4g s is above its stability limit of about %.3g s, estimated at t = %.6g s (the "
                "Jacobian's spectral radius %.3g 1/s): the results are not to be trusted; use --step %.2g or less, "
                "or --method ros34pw2",
                h, h_stable, t, rho, 0.5 * h_stable);
  return b;
}

void check_writable(const std::string& path, const std::string& what, std::size_t suffix) {
  namespace fs = std::filesystem;
  const fs::path p(path);
  const fs::path dir = p.has_parent_path() ? p.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(dir, ec))
    throw OutputError("cannot write the " + what + " '" + path + "': the folder '" + dir.string() +
                      "' does not exist (create it first, or choose another path)");
  if (path.empty()) throw OutputError("cannot write the " + what + ": its path is empty");
  if (fs::is_directory(p, ec)) throw OutputError("cannot write the " + what + " '" + path + "': it is a folder");
  // A device, a FIFO or a link would be replaced by a regular file (or written through).
  const fs::file_status st = fs::symlink_status(p, ec);
  if (!ec && fs::exists(st) && !fs::is_regular_file(st))
    throw OutputError("cannot write the " + what + " '" + path + "': it exists and is not a regular file (" +
                      (fs::is_symlink(st) ? "a link" : fs::is_fifo(st) ? "a FIFO" : "a device or socket") +
                      "); choose another path");
  if (access(dir.c_str(), W_OK) != 0)
    throw OutputError("cannot write the " + what + " '" + path + "': no permission to write in '" + dir.string() + "'");
  // Its name, and the longest name derived from it, within the file system's limit.
  const long name_max = ::pathconf(dir.c_str(), _PC_NAME_MAX);
  const std::size_t name = p.filename().string().size();
  if (name_max > 0 && name + suffix > static_cast<std::size_t>(name_max))
    throw OutputError("cannot write the " + what + " '" + path + "': its name is " + std::to_string(name) +
                      " bytes" + (suffix ? " and gets up to " + std::to_string(suffix) + " more for the files made beside it" : "") +
                      ", past the file system's limit of " + std::to_string(name_max) + " bytes; choose a shorter name");
}

FileLock::FileLock(const std::string& path, const std::string& what, bool remove) {
  // A lock file that its holder removes as it lets go: the lock taken may be on the file
  // just removed, so it holds only while the path still names the file locked.
  for (int attempt = 0;; ++attempt) {
    fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd_ < 0)
      throw OutputError("cannot write " + what + ": its lock file " + path + " cannot be made: " + std::strerror(errno));
    if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
      const int err = errno;
      ::close(fd_);
      if (err == EWOULDBLOCK) throw OutputError("another cvt-engine is writing " + what + " (" + path + " is held)");
      throw OutputError("cannot write " + what + ": the file system does not lock " + path + " (" +
                        std::strerror(err) + "); write it on a local file system");
    }
    struct stat held {}, named {};
    if (::fstat(fd_, &held) == 0 && ::stat(path.c_str(), &named) == 0 && held.st_ino == named.st_ino &&
        held.st_dev == named.st_dev)
      break;
    ::close(fd_);
    if (attempt == 8) throw OutputError("another cvt-engine is writing " + what + " (" + path + " keeps changing)");
  }
  if (remove) remove_ = path;
}

FileLock::~FileLock() {
  if (!remove_.empty()) ::unlink(remove_.c_str());
  if (fd_ >= 0) ::close(fd_);
}

void check_distinct(const std::vector<PathRole>& inputs, const std::vector<PathRole>& outputs) {
  namespace fs = std::filesystem;
  const auto same = [](const std::string& a, const std::string& b) {
    std::error_code ec;
    if (fs::exists(a, ec) && fs::exists(b, ec)) return fs::equivalent(a, b, ec);
    return fs::weakly_canonical(a, ec) == fs::weakly_canonical(b, ec);
  };
  for (std::size_t i = 0; i < outputs.size(); ++i) {
    if (outputs[i].path.empty()) continue;
    for (const PathRole& in : inputs)
      if (!in.path.empty() && same(outputs[i].path, in.path))
        throw OutputError("the " + outputs[i].role + " '" + outputs[i].path + "' is the " + in.role +
                          ": it would be overwritten; choose another path");
    for (std::size_t j = 0; j < i; ++j)
      if (!outputs[j].path.empty() && same(outputs[i].path, outputs[j].path))
        throw OutputError("the " + outputs[i].role + " '" + outputs[i].path + "' is also the " + outputs[j].role +
                          ": one would overwrite the other; choose two paths");
  }
}

}  // namespace cvt

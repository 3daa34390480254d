// The exit codes of cvt-engine (docs/cli.md), all in one place. The layers below the
// command line throw typed errors (ConfigError, OutputError, BlowUpError); main maps them.
#pragma once

namespace cvt {

inline constexpr int kExitOk = 0;
inline constexpr int kExitFailure = 1;
inline constexpr int kExitUsage = 64;        // command-line usage error (EX_USAGE of sysexits.h)
inline constexpr int kExitBlowUp = 70;       // numerical blow-up (EX_SOFTWARE): BlowUpError
inline constexpr int kExitCantCreate = 73;   // the output cannot be written (EX_CANTCREAT): OutputError
inline constexpr int kExitWallLimit = 75;    // stopped before run.max_wall, checkpoint kept (EX_TEMPFAIL: run again)
inline constexpr int kExitConfig = 78;       // bad configuration (EX_CONFIG): ConfigError
inline constexpr int kExitInterrupted = 130;  // stopped by SIGINT or SIGTERM, file kept

}  // namespace cvt

/* The command cvt-engine: its first instruction blocks SIGINT, SIGTERM and SIGHUP, then it
 * becomes the engine, cvt-engine-core beside it, in the same process (execv). The blocked
 * mask survives execv: a signal while the engine's shared libraries load waits, pending,
 * until the engine's own handlers are in place (engine/cli/main.cpp, before main), which
 * then unblock it. So every signal, from the first instruction on, is answered by the
 * engine with a message. Linked statically: it has nothing to load itself. */
#include <errno.h>
#include <limits.h>
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

int main(int argc, char** argv) {
  (void)argc;
  sigset_t stops;
  sigemptyset(&stops);
  sigaddset(&stops, SIGINT);
  sigaddset(&stops, SIGTERM);
  sigaddset(&stops, SIGHUP);
  sigprocmask(SIG_BLOCK, &stops, NULL);
  static const char kCore[] = "cvt-engine-core";
  char path[PATH_MAX];
  const ssize_t n = readlink("/proc/self/exe", path, sizeof path - sizeof kCore - 1);
  if (n <= 0) {
    fprintf(stderr, "cvt-engine: cannot find its own path (/proc/self/exe): %s\n", strerror(errno));
    return 127;
  }
  path[n] = '\0';
  char* slash = strrchr(path, '/');
  strcpy(slash ? slash + 1 : path, kCore);
  execv(path, argv);
  fprintf(stderr, "cvt-engine: cannot run the engine %s: %s\n", path, strerror(errno));
  return 127;
}

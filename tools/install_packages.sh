#!/bin/sh
# Installs the Debian packages named as arguments that are missing (make deps):
#   tools/install_packages.sh PACKAGE...
# as root with apt-get, or through sudo. A user who can do neither (not root; sudo missing,
# or asking for a password with no terminal to type it on) gets the list of packages to
# ask an administrator for, and exit 1 before apt-get runs. Nothing missing: nothing runs.
if ! command -v dpkg-query >/dev/null 2>&1; then
  echo "make: this is not a Debian system (no dpkg-query): install the equivalents of" >&2
  echo "  $*" >&2
  echo "then build with plain CMake (docs/install.md)" >&2
  exit 1
fi
missing=""
for p in "$@"; do
  dpkg-query -W -f='${Status}\n' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
missing=${missing# }
if [ "$(id -u)" = 0 ]; then
  sudo=""
elif command -v sudo >/dev/null 2>&1 && { sudo -n true 2>/dev/null || [ -t 0 ]; }; then
  sudo="sudo"
else
  cat >&2 <<MSG
make: these Debian packages are missing, and this user cannot install them (not root, no sudo):
  $missing
Ask an administrator to run
  apt-get install --no-install-recommends $missing
then run make again; or, with the required ones installed, build with plain CMake and leave
out the optional parts (docs/install.md).
MSG
  exit 1
fi
echo "installing: $missing"
$sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends $missing >/dev/null
rc=$?
if [ $rc != 0 ]; then
  echo "make: apt-get could not install: $missing (exit $rc)" >&2
  exit 1
fi

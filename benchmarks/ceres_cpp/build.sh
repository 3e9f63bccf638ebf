#!/usr/bin/env bash
# Build the benchmark-only C++ Ceres program (benchmarks/ceres_cpp/ceres_bench) against Debian's
# libceres-dev (Ceres 2.1.0). Optional: benchmarks.run uses it as peer "ceres_cpp" when built.
#   bash benchmarks/ceres_cpp/build.sh            # installs libceres-dev if missing (needs root)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
if [ ! -f /usr/include/ceres/ceres.h ]; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libceres-dev
  else
    echo "libceres-dev is not installed: sudo apt-get install libceres-dev" >&2
    exit 1
  fi
fi
g++ -O3 -DNDEBUG -march=native -std=c++17 -I/usr/include/eigen3 \
  "$here/bench.cc" -o "$here/ceres_bench" -lceres -lglog -lgflags -lpthread
echo "built $here/ceres_bench"

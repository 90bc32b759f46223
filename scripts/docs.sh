#!/usr/bin/env bash
# SPDX-License-Identifier: BSD-3-Clause
# The API reference of the public headers (Doxygen): HTML in build-docs/html/index.html. Fails when
# Doxygen reports any warning (a broken reference, a parameter documented under a wrong name, a
# half-documented parameter list); the test command runs it.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v doxygen >/dev/null || bash scripts/setup.sh
rm -rf build-docs && mkdir -p build-docs
doxygen Doxyfile
if [ -s build-docs/warnings.log ]; then
  echo "docs: $(grep -c 'warning:' build-docs/warnings.log) Doxygen warning(s):" >&2
  cat build-docs/warnings.log >&2
  exit 1
fi
python3 scripts/python_api.py build-docs/python-api.md
echo "docs: build-docs/html/index.html, no warnings; the Python API in build-docs/python-api.md"

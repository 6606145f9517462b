#!/usr/bin/env bash
# Every C++ source of the repository is clang-format clean (the repo's .clang-format). `make format`
# fixes what this finds.
set -u
cd "${1:-.}" || exit 2
if ! command -v clang-format >/dev/null 2>&1; then
  echo "clang-format is not installed (the Makefile installs it): nothing checked"
  exit 1
fi
bad=$(git ls-files '*.cpp' '*.h' | while read -r f; do clang-format --dry-run -Werror "$f" >/dev/null 2>&1 || echo "$f"; done)
if [ -n "$bad" ]; then
  echo "not clang-format clean (run \`make format\`):"
  echo "$bad"
  exit 1
fi
echo "format: $(git ls-files '*.cpp' '*.h' | wc -l) sources clang-format clean"

#!/usr/bin/env bash
# The house style (.clang-format) holds for every C++ file in the repository: lists the files
# clang-format would change and fails if there are any. Fix with:
#   git ls-files '*.cpp' '*.h' | xargs clang-format -i
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v clang-format >/dev/null; then
  echo "clang-format is not installed (scripts/setup.sh installs it)" >&2
  exit 1
fi
if ! git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
  echo "not a git checkout: nothing to check" >&2
  exit 77
fi
bad=0
while IFS= read -r f; do
  [ -f "$f" ] || continue
  if ! clang-format --dry-run -Werror "$f" >/dev/null 2>&1; then
    echo "not in the house style: $f" >&2
    bad=$((bad + 1))
  fi
done < <(git ls-files '*.cpp' '*.h')
if [ "$bad" -ne 0 ]; then
  echo "$bad file(s) differ from .clang-format; run: git ls-files '*.cpp' '*.h' | xargs clang-format -i" >&2
  exit 1
fi
echo "every C++ file is in the house style"

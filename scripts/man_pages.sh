#!/usr/bin/env bash
# Man pages generated from --help by Debian's help2man: ltbake.1, and ltbake-COMMAND.1 for
# every command of `ltbake --list-commands` (the one command list in cli/app.cpp), so that
# `man ltbake-sample` works as `man git-commit` does. Run by `cmake --install` into
# PREFIX/share/man/man1:
#   scripts/man_pages.sh path/to/ltbake OUTDIR
set -euo pipefail
ltb=$1
out=$2
command -v help2man > /dev/null || { echo "man_pages: help2man is missing (scripts/setup.sh installs it)" >&2; exit 1; }
ltb=$(realpath "$ltb")
ver=$("$ltb" --version | head -1 | cut -d' ' -f2)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$out"
page() {  # page NAME DESCRIPTION PROGRAM
  help2man --no-info --no-discard-stderr --version-string "$ver" --name "$2" -o "$out/$1.1" "$3" ||
    { echo "man_pages: help2man failed for $1" >&2; exit 1; }
}
page ltbake "bake and compress light transport matrices for all-frequency relighting" "$ltb"
# Each command's one-line description, from the Subcommands section of `ltbake --help`.
"$ltb" --help | awk '/^Subcommands:/ { on = 1; next } on && /^  [a-z]/ { n = $1; $1 = ""; sub(/^ +/, ""); print n "\t" $0 }' \
  > "$tmp/descriptions"
n=0
while read -r cmd _; do
  ln -s "$ltb" "$tmp/ltbake-$cmd"  # ltbake-COMMAND runs `ltbake COMMAND` (cli/main.cpp)
  desc=$(awk -F'\t' -v c="$cmd" '$1 == c { print $2 }' "$tmp/descriptions")
  page "ltbake-$cmd" "${desc:-ltbake $cmd}" "$tmp/ltbake-$cmd"
  n=$((n + 1))
done < <("$ltb" --list-commands)
[ "$n" -gt 0 ] || { echo "man_pages: '$ltb --list-commands' named no command" >&2; exit 1; }
echo "man_pages: $((n + 1)) pages in $out"

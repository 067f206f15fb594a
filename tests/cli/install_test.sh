#!/usr/bin/env bash
# `cmake --install` (what `make install PREFIX=...` runs) into a fresh prefix: ltbake, a link
# ltbake-<stage> for each stage executable the build tree has (the build's links are checked
# against the command list by tests/pipeline/stage_commands_test.cpp), no stale ltbake-* link
# left from an earlier install, each link running its stage, the bash and zsh completions,
# the man pages, and `import ltbake` from the installed package.
#   install_test.sh BUILD_DIR
set -euo pipefail
build=$1
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
fail() { echo "install_test: $*" >&2; exit 1; }

mkdir -p "$tmp/prefix/bin"
ln -s ltbake "$tmp/prefix/bin/ltbake-retired"  # a stage an earlier version had
cmake --install "$build" --prefix "$tmp/prefix" > "$tmp/install.log" || { cat "$tmp/install.log"; fail "install failed"; }
bin=$tmp/prefix/bin
[ -x "$bin/ltbake" ] && [ ! -L "$bin/ltbake" ] || fail "no ltbake binary in $bin"
[ ! -e "$bin/ltbake-retired" ] && [ ! -L "$bin/ltbake-retired" ] || fail "the stale link ltbake-retired was kept"

want=$(cd "$build" && find . -maxdepth 1 -name 'ltbake-*' -type l -printf '%f\n' | sort)
have=$(cd "$bin" && find . -maxdepth 1 -name 'ltbake-*' -type l -printf '%f\n' | sort)
[ -n "$want" ] || fail "the build tree $build has no ltbake-* links"
[ "$want" = "$have" ] || fail "installed links differ from the build tree's: want [$want], have [$have]"
for link in $have; do
  [ "$(readlink "$bin/$link")" = ltbake ] || fail "$link points to $(readlink "$bin/$link"), not ltbake"
  stage=${link#ltbake-}
  out=$("$bin/$link" --help) || fail "$link --help exited $?"
  grep -q -- "$stage" <<< "$out" || fail "$link --help does not describe '$stage': $out"
done
# A path a user has on PATH: the installed binary runs on its own (no build tree needed).
PATH="$bin:$PATH" ltbake --version | grep -q '^ltbake ' || fail "installed ltbake --version failed"

# Bash completion, from the installed file: commands from the command list, a stage's flags
# from its --help (for ltbake and for ltbake-<stage> alike).
comp=$tmp/prefix/share/bash-completion/completions/ltbake
[ -f "$comp" ] || fail "no bash completion at $comp"
complete_words() {  # complete_words WORD... : what completing the last word offers
  PATH="$bin:$PATH" bash -c 'source "$0"; COMP_WORDS=("${@}"); COMP_CWORD=$((${#COMP_WORDS[@]} - 1)); _ltbake;
    printf "%s\n" "${COMPREPLY[@]}"' "$comp" "$@"
}
[ "$(complete_words ltbake qua)" = quantize ] || fail "ltbake qua<TAB> offers '$(complete_words ltbake qua)'"
got=$(complete_words ltbake sample --sp | sort | tr '\n' ' ')
[ "$got" = "--sparse --spp " ] || fail "ltbake sample --sp<TAB> offers '$got'"
got=$(complete_words ltbake-quantize --error | tr '\n' ' ')
[ "$got" = "--error-ratio " ] || fail "ltbake-quantize --error<TAB> offers '$got'"
PATH="$bin:$PATH" bash -c 'source "$0"; complete -p ltbake-sample' "$comp" > /dev/null ||
  fail "no completion registered for ltbake-sample"

# Zsh completion, from the installed file, in a real interactive zsh (zsh/zpty, compinit):
# a command, a stage's flag for ltbake and for ltbake-<stage>, an ambiguous flag listed.
zfn=$tmp/prefix/share/zsh/site-functions
[ -f "$zfn/_ltbake" ] || fail "no zsh completion at $zfn/_ltbake"
command -v zsh > /dev/null || fail "zsh is not installed (scripts/setup.sh installs it)"
mkdir "$tmp/zsh"
zsh -f "$(dirname "$0")/zsh_completion.zsh" "$zfn" "$bin" "$tmp/zsh" "ltbake qua" "ltbake-quantize --error" \
  "ltbake sample --sp" "ltbake --ver" || fail "the zsh completion test did not run"
for want in "1:ltbake quantize " "2:ltbake-quantize --error-ratio " "3:ltbake sample --sp" "4:ltbake --version "; do
  got=$(cat "$tmp/zsh/${want%%:*}.buffer")
  [ "$got" = "${want#*:}" ] || fail "zsh: TAB gave '$got', not '${want#*:}'"
done
grep -q -- "--sparse" "$tmp/zsh/3.screen" && grep -q -- "--spp" "$tmp/zsh/3.screen" ||
  fail "zsh: ltbake sample --sp<TAB> did not list --sparse and --spp: $(cat -v "$tmp/zsh/3.screen")"

# A man page for ltbake and every command (stages and the rest), rendered by man: its NAME
# line names the command and its options are the command's own.
man1=$tmp/prefix/share/man/man1
[ -f "$man1/ltbake.1" ] || fail "no man page ltbake.1 in $man1"
while read -r cmd _; do
  [ -f "$man1/ltbake-$cmd.1" ] || fail "no man page ltbake-$cmd.1 in $man1"
done < <("$bin/ltbake" --list-commands)
page=$(MANWIDTH=200 man -l "$man1/ltbake-quantize.1" 2> /dev/null) || fail "man -l ltbake-quantize.1 failed"
grep -q "ltbake-quantize - quantize a column-transform output" <<< "$page" || fail "ltbake-quantize.1 NAME: $page"
grep -q -- "--error-ratio" <<< "$page" || fail "ltbake-quantize.1 lacks --error-ratio: $page"

py=$(find "$tmp/prefix/lib" -path '*-packages/ltbake/__init__.py' | head -1)
[ -n "$py" ] || fail "no Python package under $tmp/prefix/lib: $(cat "$tmp/install.log")"
site=$(dirname "$(dirname "$py")")
got=$(cd "$tmp" && PYTHONPATH="$site" /usr/bin/python3 -c 'import ltbake; print(ltbake.__file__)')
[ "$got" = "$py" ] || fail "import ltbake found $got, not the installed $py"
echo "install_test: ok ($(wc -w <<< "$have") stage executables, Python package in $site)"

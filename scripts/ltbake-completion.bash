# Bash completion for ltbake and its stage executables (ltbake-<stage>). Nothing is listed
# here: the commands come from `ltbake --list-commands` (the one command list, cli/app.cpp)
# and each command's flags from its own --help, so the completion never falls behind the
# binary. Installed by `make install` as PREFIX/share/bash-completion/completions/ltbake;
# or `source scripts/ltbake-completion.bash` with ltbake on PATH.

# The flags a --help text lists: option lines start with "-x," or "--name".
_ltbake_flags() {
  "$@" --help 2>/dev/null | grep -oE '^ +(-[A-Za-z],)?--[A-Za-z0-9][A-Za-z0-9-]*' | tr ',' '\n' | tr -d ' '
}

_ltbake() {
  local cur=${COMP_WORDS[COMP_CWORD]} prog=${COMP_WORDS[0]}
  local -a cmd
  if [[ ${prog##*/} == ltbake-* ]]; then  # a stage executable: it is its command already
    cmd=("$prog")
  elif ((COMP_CWORD == 1)); then
    local names
    names=$("$prog" --list-commands 2>/dev/null | cut -d' ' -f1)
    if [[ $cur == -* ]]; then
      mapfile -t COMPREPLY < <(compgen -W "--help --version" -- "$cur")
    else
      mapfile -t COMPREPLY < <(compgen -W "$names" -- "$cur")
    fi
    return
  else
    cmd=("$prog" "${COMP_WORDS[1]}")
  fi
  if [[ $cur == -* ]]; then
    mapfile -t COMPREPLY < <(compgen -W "$(_ltbake_flags "${cmd[@]}")" -- "$cur")
  fi  # else: the shell's default, file names (complete -o default)
}

complete -o default -F _ltbake ltbake
for _ltbake_stage in $(ltbake --list-commands 2>/dev/null | awk '$2 == "stage" {print $1}'); do
  complete -o default -F _ltbake "ltbake-$_ltbake_stage"
done
unset _ltbake_stage

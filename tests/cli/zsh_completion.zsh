#!/usr/bin/env zsh
# Zsh completion of the installed _ltbake (scripts/_ltbake), in a real interactive zsh under
# zsh/zpty with compinit: TAB on a partial line, then the line as completion left it (written
# out by a widget) and what the shell listed. Called by tests/cli/install_test.sh.
#   zsh -f zsh_completion.zsh SITE_FUNCTIONS_DIR BIN_DIR OUT_DIR LINE...
# For each LINE, OUT_DIR/N.buffer holds the completed line and OUT_DIR/N.screen the terminal.
emulate -L zsh
zmodload zsh/zpty || { print -u2 "zsh_completion: no zsh/zpty module"; exit 1; }
fn=$1 bin=$2 out=$3
shift 3
integer n=0
for line in "$@"; do
  (( n++ ))
  zpty z zsh -f -i
  # A quiet shell: no prompt, the functions directory first on $fpath, ltbake on PATH; ^B
  # writes the line to a file and clears it (nothing is run).
  zpty -w z "PS1='' RPROMPT=''; unsetopt beep; fpath=($fn \$fpath); PATH=$bin:\$PATH; autoload -U compinit; compinit -u -D"
  zpty -w z "dump() { print -r -- \"\$BUFFER\" > $out/$n.buffer; BUFFER=''; }; zle -N dump; bindkey '^B' dump"
  zpty -w -n z "$line"$'\t'$'\x02'
  zpty -w z "print -r -- DONE-\$((40+2))"  # the marker's text is not in the command line echoed
  screen=''
  integer waited=0
  while [[ $screen != *DONE-42* ]] && (( waited < 200 )); do
    if zpty -r -t z chunk; then screen+=$chunk; else sleep 0.05; (( waited++ )); fi
  done
  zpty -d z
  print -r -- "$screen" > $out/$n.screen
  [[ $screen == *DONE-42* ]] || { print -u2 "zsh_completion: the shell did not finish the line '$line'"; exit 1; }
done

#!/usr/bin/env bash
# Prints the directory of the CC0 environment maps that Debian's blender-data ships
# (studiolights/world/*.exr, 1024x512 lat-long, DWAB-compressed; docs/ENVMAPS.md).
# Debian installs them unversioned (/usr/share/blender/datafiles/...); upstream layouts put
# a version directory in between (/usr/share/blender/<version>/datafiles/...): both are
# searched, the newest version first. Exit 1 (with a hint on stderr) when none is installed.
set -euo pipefail

shopt -s nullglob
for dir in /usr/share/blender/datafiles/studiolights/world \
           $(ls -d /usr/share/blender/*/datafiles/studiolights/world 2>/dev/null | sort -rV); do
  maps=("$dir"/*.exr)
  if [ ${#maps[@]} -gt 0 ]; then
    echo "$dir"
    exit 0
  fi
done
echo "find_envmaps: no environment maps found; install them with: sudo apt-get install blender-data" >&2
echo "  (or run scripts/setup.sh)" >&2
exit 1

#!/usr/bin/env python3
"""docs/ARCHITECTURE.md's size rule: no function over 120 lines in format/ stages/ pipeline/
cli/ python/ without a comment saying why ("Over 120 lines: ...") just above it.

A brace scanner, not a parser: comments, string literals and preprocessor lines are blanked,
then a `{` whose text since the last `;`, `{` or `}` holds a `)` and that is not inside a
function opens a function (lambdas inside it count towards it). Prints each function over
the limit without a reason (file:line name length) and exits 1 if there is one.

    python3 tests/function_length_check.py [ROOT]
"""
import os
import re
import sys

LIMIT = 120
FOLDERS = ("format", "stages", "pipeline", "cli", "python")
REASON = "Over 120 lines:"


def blank(text):
    """The source with comments, string and character literals and preprocessor lines as spaces
    (newlines kept, so line numbers hold)."""
    out, i, n = [], 0, len(text)
    while i < n:
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
        elif text.startswith('R"', i) and (m := re.match(r'R"([^(\s]*)\(', text[i:])):
            end = text.find(")" + m.group(1) + '"', i)
            j = n if end < 0 else end + len(m.group(1)) + 2
        elif text[i] in "\"'":
            j = i + 1
            while j < n and text[j] != text[i] and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            j += 1
        else:
            out.append(text[i])
            i += 1
            continue
        out.append(re.sub(r"[^\n]", " ", text[i:j]))
        i = j
    return re.sub(r"(?m)^[ \t]*#.*$", "", "".join(out))


def functions(text):
    """(line of the body's `{`, last line, name, first line of the signature) of every
    top-level function in the text."""
    code = blank(text)
    stack, last, line, start = [], 0, 1, None
    for i, c in enumerate(code):
        if c == "\n":
            line += 1
        elif c == "{":
            head = code[last:i]
            if "f" not in stack and ")" in head and not re.match(r"\s*(namespace|class|struct|enum|union)\b", head):
                names = re.findall(r"([\w:~]+)\s*\(", head)
                lead = head[: len(head) - len(head.lstrip())].count("\n")
                start = (line, names[0] if names else "?", line - head.count("\n") + lead)
                stack.append("f")
            else:
                stack.append("o")
            last = i + 1
        elif c == "}":
            kind = stack.pop() if stack else "o"
            if kind == "f" and "f" not in stack:
                yield start[0], line, start[1], start[2]
            last = i + 1
        elif c == ";":
            last = i + 1


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..")
    bad = 0
    for folder in FOLDERS:
        for dirpath, _, files in os.walk(os.path.join(root, folder)):
            for f in sorted(files):
                if not f.endswith((".cpp", ".h")):
                    continue
                path = os.path.join(dirpath, f)
                text = open(path, encoding="utf-8", errors="replace").read()
                lines = text.split("\n")
                for first, last, name, signature in functions(text):
                    length = last - first + 1
                    if length <= LIMIT:
                        continue
                    # The reason sits in the comment block just above the signature.
                    k = signature - 2
                    above = []
                    while k >= 0 and lines[k].lstrip().startswith("//"):
                        above.append(lines[k])
                        k -= 1
                    if not any(REASON in a for a in above):
                        print(f"{os.path.relpath(path, root)}:{first}: {name} is {length} lines (over {LIMIT}); "
                              f"split it, or say why above it ('// {REASON} ...')")
                        bad += 1
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

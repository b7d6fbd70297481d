#!/usr/bin/env python3
"""Lists every Rust function longer than 150 lines in the firmware (`src/`, `build.rs`) and the
simulator (`host-sim/src/`), outside `#[cfg(test)]` items and the tables of ALLOWED.

A function's length counts its lines from the `fn` line to its closing brace, both included;
braces are counted with strings, raw strings, char literals and comments skipped. A function
nested in another counts in its parent too. Each over-long function is printed as
`path:line name lines`, longest first.

Usage: python3 scripts/check-fn-length.py   (exit status 1 when one is listed)
"""

import os
import re
import sys

MAX_LINES = 150

ROOTS = ["src", "host-sim/src", "build.rs"]

# Functions whose body is mostly a literal table, exempted with the reason: {(path, name): why}.
ALLOWED = {}

IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def blank_out(text):
    """The text with comments, strings and char literals replaced by spaces (newlines kept),
    so that every brace left is code."""
    out = []
    i, n = 0, len(text)

    def keep_lines(s):
        return "".join("\n" if c == "\n" else " " for c in s)

    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(keep_lines(text[i:j]))
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(keep_lines(text[i:j]))
            i = j
        elif (m := re.compile(r'b?r(#*)"').match(text, i)) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            end = '"' + m.group(1)
            j = text.find(end, m.end())
            j = n if j < 0 else j + len(end)
            out.append(keep_lines(text[i:j]))
            i = j
        elif c == '"' or (c == "b" and text.startswith('b"', i) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_"))):
            j = i + (2 if c == "b" else 1)
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            j += 1
            out.append(keep_lines(text[i:j]))
            i = j
        elif c == "'":
            # A char literal ('x', '\n', '\u{..}', '{') or a lifetime ('a): a literal closes
            # within a few characters.
            m = re.compile(r"'(\\u\{[0-9a-fA-F]*\}|\\.|[^\\'])'").match(text, i)
            if m:
                out.append(keep_lines(m.group(0)))
                i = m.end()
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def matching_brace(code, open_at):
    """The index of the brace closing the one at `open_at`."""
    depth = 0
    for j in range(open_at, len(code)):
        if code[j] == "{":
            depth += 1
        elif code[j] == "}":
            depth -= 1
            if depth == 0:
                return j
    return len(code) - 1


def test_spans(code):
    """The (start, end) spans of the items under `#[cfg(test)]` (a module or a function)."""
    spans = []
    for m in re.finditer(r"#\s*\[\s*cfg\s*\(\s*test\s*\)\s*\]", code):
        j = m.end()
        # The item's body: the first brace before any `;` (a `mod tests;` has none).
        while j < len(code) and code[j] not in "{;":
            j += 1
        if j < len(code) and code[j] == "{":
            spans.append((m.start(), matching_brace(code, j)))
    return spans


def long_functions(path):
    """(line, name, lines) of each function of the file over MAX_LINES lines."""
    with open(path, encoding="utf-8") as f:
        code = blank_out(f.read())
    skipped = test_spans(code)
    found = []
    for m in re.finditer(r"\bfn\s+([A-Za-z_][A-Za-z0-9_]*)", code):
        if any(a <= m.start() <= b for a, b in skipped):
            continue
        # The body opens at the first `{` outside the signature's parentheses; a `;` first
        # means a declaration without a body (a trait method, an extern fn).
        depth, j = 0, m.end()
        while j < len(code):
            ch = code[j]
            if ch in "([":
                depth += 1
            elif ch in ")]":
                depth -= 1
            elif depth == 0 and ch in "{;":
                break
            j += 1
        if j >= len(code) or code[j] == ";":
            continue
        end = matching_brace(code, j)
        first = code.count("\n", 0, m.start()) + 1
        last = code.count("\n", 0, end) + 1
        lines = last - first + 1
        if lines > MAX_LINES:
            found.append((first, m.group(1), lines))
    return found


def rust_files(root):
    if os.path.isfile(root):
        yield root
        return
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames.sort()
        for name in sorted(filenames):
            if name.endswith(".rs"):
                yield os.path.join(dirpath, name)


def main():
    os.chdir(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    over = []
    for root in ROOTS:
        for path in rust_files(root):
            for line, name, lines in long_functions(path):
                if (path, name) in ALLOWED:
                    continue
                over.append((lines, path, line, name))
    for lines, path, line, name in sorted(over, key=lambda o: (-o[0], o[1], o[2])):
        print(f"{path}:{line} {name} {lines} lines")
    if over:
        print(
            f"{len(over)} function(s) over {MAX_LINES} lines: split them into named steps",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

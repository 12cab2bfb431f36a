#!/usr/bin/env python3
"""The house's size limits: no source file over MAX_FILE lines, no function over MAX_FUNCTION.

Reads every .cc/.h under the source directories (tests, generated code and third-party code
aside) and prints each file or function over its limit; exits 1 when there is one. A function is
a brace block at namespace scope (or a member function's body in a class) whose head has a
parameter list; its length is counted from the line of its opening brace to the line of its
closing brace, both included, lambdas and local classes inside it counted as its own lines (as
clang-tidy's readability-function-size counts them).

The brace scanner skips comments, string and character literals (raw strings too) and
preprocessor lines, which is enough for this codebase's style; `clang-tidy
--checks=readability-function-size` gives the same functions where both were compared.

usage: house_limits.py [--root DIR] [--max-file N] [--max-function N] [--list N]
"""
import argparse
import os
import re
import sys

SOURCE_DIRS = ["util", "core", "importers", "formats", "storage", "server", "client", "bench",
               "tools"]
HEAD_KEYWORDS = re.compile(r"^\s*(?:template\s*<.*>\s*)?(namespace|struct|class|enum|union|extern)\b",
                           re.S)


def strip_code(text):
    """The text with comments, literals and preprocessor lines blanked (newlines kept)."""
    out = []
    i, n = 0, len(text)
    at_line_start = True
    while i < n:
        c = text[i]
        if at_line_start and c == "#":
            # a preprocessor line, with its continuations
            while i < n and text[i] != "\n":
                if text[i] == "\\" and i + 1 < n and text[i + 1] == "\n":
                    out.append(" \n")
                    i += 2
                    continue
                out.append(" ")
                i += 1
            continue
        if c == "\n":
            out.append(c)
            at_line_start = True
            i += 1
            continue
        if not c.isspace():
            at_line_start = False
        if text.startswith("//", i):
            while i < n and text[i] != "\n":
                out.append(" ")
                i += 1
            continue
        if text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
            continue
        m = re.match(r'R"([^(\s]*)\(', text[i:i + 20])
        if m and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            end = text.find(")" + m.group(1) + '"', i)
            j = n if end < 0 else end + len(m.group(1)) + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
            continue
        if c in "\"'":
            if c == "'" and i > 0 and text[i - 1].isalnum():  # a digit separator: 1'000
                out.append(" ")
                i += 1
                continue
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
            continue
        out.append(c)
        i += 1
    return "".join(out)


def functions(path):
    """(name, first line, length in lines) of each function body in the file."""
    code = strip_code(open(path, encoding="utf-8", errors="replace").read())
    found = []
    # a stack of open blocks: (kind, start offset, head); kind "scope" for namespaces, classes and the
    # like (their contents are scanned for functions), "function", or "other"
    stack = []
    head_start = 0
    for i, c in enumerate(code):
        if c in ";":
            if not stack or stack[-1][0] == "scope":
                head_start = i + 1
        elif c == "{":
            in_function = any(entry[0] == "function" for entry in stack)
            head = code[head_start:i]
            if in_function:
                kind = "other"
            elif HEAD_KEYWORDS.match(head):
                kind = "scope"
            elif ")" in head and not re.search(r"=\s*$", head):
                kind = "function"
            else:
                kind = "other"
            stack.append((kind, i, head))
            if kind in ("scope", "other"):
                head_start = i + 1
        elif c == "}":
            if not stack:
                continue
            kind, start, head = stack.pop()
            if kind == "function":
                first = code.count("\n", 0, start) + 1
                last = code.count("\n", 0, i) + 1
                name = re.findall(r"([~\w:]+(?:operator\S*)?)\s*\(", head)
                found.append((name[0] if name else "?", first, last - first + 1))
            if not stack or stack[-1][0] == "scope":
                head_start = i + 1
    return found


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--root", default=os.path.join(os.path.dirname(__file__), "..", ".."))
    parser.add_argument("--max-file", type=int, default=700)
    parser.add_argument("--max-function", type=int, default=80)
    parser.add_argument("--list", type=int, default=0,
                        help="also print the N longest functions and files")
    args = parser.parse_args()
    root = os.path.abspath(args.root)
    over = []
    all_functions, all_files = [], []
    for top in SOURCE_DIRS:
        for dirpath, _, names in os.walk(os.path.join(root, top)):
            for name in sorted(names):
                if not name.endswith((".cc", ".h")) or ".pb." in name:
                    continue
                path = os.path.join(dirpath, name)
                rel = os.path.relpath(path, root)
                lines = sum(1 for _ in open(path, encoding="utf-8", errors="replace"))
                all_files.append((lines, rel))
                if lines > args.max_file:
                    over.append(f"{rel}: {lines} lines (limit {args.max_file})")
                for fn, first, length in functions(path):
                    all_functions.append((length, f"{rel}:{first}", fn))
                    if length > args.max_function:
                        over.append(f"{rel}:{first}: function {fn} is {length} lines "
                                    f"(limit {args.max_function})")
    if args.list:
        for length, where, fn in sorted(all_functions, reverse=True)[:args.list]:
            print(f"  {length:5d}  {where}  {fn}")
        for lines, rel in sorted(all_files, reverse=True)[:args.list]:
            print(f"  {lines:5d}  {rel}")
    for line in over:
        print(line)
    print(f"house_limits: {len(all_files)} files, {len(all_functions)} functions, "
          f"{len(over)} over the limits")
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())

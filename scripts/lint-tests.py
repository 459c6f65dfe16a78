#!/usr/bin/env python3
"""Finds GoogleTest tests that cannot fail.

Scans *_test.cc files for
  self-compare   an assertion comparing a value with itself: EXPECT_EQ(x, x),
                 EXPECT_NEAR(x, x, tol), EXPECT_TRUE(x == x), ... (expressions that differ
                 only in spacing count as the same; an expression that calls a function
                 with arguments, or a free function, is left alone: calling it twice may
                 give two values, as a determinism test wants);
  constant       an assertion on a literal: EXPECT_TRUE(true), ASSERT_FALSE(0), ...;
  no-assertion   a TEST / TEST_F / TEST_P / TYPED_TEST body with no EXPECT_* / ASSERT_* /
                 ADD_FAILURE / FAIL, and no call of a helper that asserts (a function,
                 lambda or macro of the same file, or of tests/test_support.*, whose body
                 does); a body that only skips (GTEST_SKIP) is flagged too;
  empty-message  EXPECT_THROW_WITH_MESSAGE(..., "") or no substring at all (reads nothing).
A line that ends in `// lint-tests: allow <kind>` is exempt from <kind> (for the tests of
the test helpers themselves, which must show the bad form failing).

Usage: lint-tests.py [PATH ...]   (default: the repository; directories named build*,
       .git and lint_fixtures are skipped unless given explicitly)
       lint-tests.py --self-test DIR   checks that the findings in DIR are exactly the
       lines marked `// LINT-EXPECT: <kind>` (exit 0 when they are).
Prints `file:line: kind: text` per finding; exits 1 when there is any.
"""

import os
import re
import sys

ASSERT_TOKEN = re.compile(r"\b(?:EXPECT|ASSERT)_[A-Z0-9_]+\s*\(|\bADD_FAILURE(?:_AT)?\s*\(|"
                          r"\bFAIL\s*\(")
TEST_HEADER = re.compile(r"^[ \t]*(TEST|TEST_F|TEST_P|TYPED_TEST|TYPED_TEST_P)\s*\(",
                         re.MULTILINE)
COMPARISONS = {"EQ", "NE", "LT", "LE", "GT", "GE", "NEAR", "DOUBLE_EQ", "FLOAT_EQ", "STREQ",
               "STRNE", "STRCASEEQ", "STRCASENE", "PRED_FORMAT2"}
ASSERTION_CALL = re.compile(r"\b(EXPECT|ASSERT)_([A-Z0-9_]+)\s*\(")
SKIP_DIRS = {".git", "lint_fixtures"}


def blank_comments(text, keep_strings=True):
    """Comments (and, unless keep_strings, string/char literal contents) become spaces;
    newlines and offsets are kept so line numbers stay right."""
    out = list(text)
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            for k in range(i, j):
                out[k] = " "
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            for k in range(i, j):
                if out[k] != "\n":
                    out[k] = " "
            i = j
        elif text.startswith('R"', i) and (i == 0 or not (text[i - 1].isalnum() or
                                                          text[i - 1] == "_")):
            m = re.match(r'R"([^(\s]*)\(', text[i:])
            if not m:
                i += 1
                continue
            end = text.find(")" + m.group(1) + '"', i)
            end = n if end < 0 else end + len(m.group(1)) + 2
            if not keep_strings:
                for k in range(i + 1, end - 1):
                    if out[k] != "\n":
                        out[k] = " "
            i = end
        elif c in "\"'":
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            if not keep_strings:
                for k in range(i + 1, min(j, n)):
                    out[k] = " "
            i = j + 1
        else:
            i += 1
    return "".join(out)


def matching(text, open_index):
    """Index of the bracket closing the one at open_index (strings/comments already
    blanked), or -1."""
    pairs = {"(": ")", "[": "]", "{": "}"}
    stack = []
    for i in range(open_index, len(text)):
        c = text[i]
        if c in pairs:
            stack.append(pairs[c])
        elif c in ")]}":
            if not stack or stack.pop() != c:
                return -1
            if not stack:
                return i
    return -1


def split_arguments(code, text=None):
    """Top-level comma-separated arguments of a call's inside, split where `code` (strings
    blanked) has its commas, cut out of `text` (strings kept; default `code`)."""
    text = code if text is None else text
    args, depth, start = [], 0, 0
    for i, c in enumerate(code):
        if c in "([{":
            depth += 1
        elif c in ")]}":
            depth -= 1
        elif c == "," and depth == 0:
            args.append(text[start:i])
            start = i + 1
    args.append(text[start:])
    return [a.strip() for a in args]


def normalise(expression):
    return re.sub(r"\s+", "", expression)


def may_differ_between_evaluations(expression):
    """True when evaluating `expression` twice can give two values: it calls something
    other than an argument-less member accessor (x.size(), p->value())."""
    without_accessors = re.sub(r"(\.|->)\s*[A-Za-z_]\w*\s*\(\s*\)", "", expression)
    return "(" in without_accessors


def line_of(text, index):
    return text.count("\n", 0, index) + 1


def assertion_helpers(texts):
    """Names of functions, lambdas and macros whose bodies assert, in `texts` (comments
    blanked), to a fixpoint (a helper that calls a helper asserts)."""
    bodies = {}
    for text in texts:
        for m in re.finditer(r"^[ \t]*#[ \t]*define[ \t]+(\w+)((?:[^\n]*\\\n)*[^\n]*)", text,
                             re.MULTILINE):
            bodies.setdefault(m.group(1), []).append(m.group(2))
        # Functions and methods: name(...) [const] [override] [-> type] {
        for m in re.finditer(r"\b([A-Za-z_]\w*)\s*(?:<[^<>;{}()]*>)?\s*\(", text):
            name = m.group(1)
            if name in {"if", "for", "while", "switch", "catch", "return", "sizeof",
                        "TEST", "TEST_F", "TEST_P", "TYPED_TEST", "TYPED_TEST_P"}:
                continue
            close = matching(text, m.end() - 1)
            if close < 0:
                continue
            rest = re.match(r"\s*(?:const\s*)?(?:noexcept\s*)?(?:override\s*)?"
                            r"(?:->\s*[\w:<>,\s&*]+?\s*)?\{", text[close + 1:])
            if not rest:
                continue
            brace = close + rest.end()
            end = matching(text, brace)
            if end > 0:
                bodies.setdefault(name, []).append(text[brace:end])
        # Lambdas bound to a name: auto name = [...](...) ... {
        for m in re.finditer(r"\b(?:auto|std::function<[^;]*?>)\s+(\w+)\s*=\s*\[", text):
            brace = text.find("{", m.end())
            if brace < 0:
                continue
            end = matching(text, brace)
            if end > 0:
                bodies.setdefault(m.group(1), []).append(text[brace:end])
    helpers = set()
    changed = True
    while changed:
        changed = False
        for name, texts_of_name in bodies.items():
            if name in helpers:
                continue
            if any(asserts(body, helpers) for body in texts_of_name):
                helpers.add(name)
                changed = True
    return helpers


def asserts(body, helpers):
    if ASSERT_TOKEN.search(body):
        return True
    for m in re.finditer(r"\b([A-Za-z_]\w*)\s*(?:<[^<>;{}()]*>)?\s*\(", body):
        if m.group(1) in helpers:
            return True
    return False


def lint_text(path, raw, shared_helpers):
    findings = []
    text = blank_comments(raw, keep_strings=True)
    code = blank_comments(raw, keep_strings=False)  # for structure: no brackets in strings

    for m in ASSERTION_CALL.finditer(code):
        kind = m.group(2)
        close = matching(code, m.end() - 1)
        if close < 0:
            continue
        args_code = split_arguments(code[m.end():close])
        args_text = split_arguments(code[m.end():close], text[m.end():close])
        line = line_of(code, m.start())
        shown = normalise(text[m.start():close + 1])[:80]
        if kind in COMPARISONS and len(args_text) >= 2:
            a, b = (args_text[1], args_text[2]) if kind == "PRED_FORMAT2" else args_text[:2]
            if normalise(a) == normalise(b) and not may_differ_between_evaluations(a):
                findings.append((path, line, "self-compare", shown))
        elif kind in {"TRUE", "FALSE"} and args_text:
            value = normalise(args_text[0])
            if value in {"true", "false", "0", "1"}:
                findings.append((path, line, "constant", shown))
            else:
                sides = re.split(r"==|!=|<=|>=", args_code[0])
                if len(sides) == 2 and normalise(sides[0]) and \
                        normalise(sides[0]) == normalise(sides[1]) and \
                        not may_differ_between_evaluations(sides[0]):
                    findings.append((path, line, "self-compare", shown))
        elif kind == "THROW_WITH_MESSAGE":
            if len(args_text) < 3 or any(normalise(a) == '""' for a in args_text[2:]):
                findings.append((path, line, "empty-message", shown))

    helpers = shared_helpers | assertion_helpers([code])
    for m in TEST_HEADER.finditer(code):
        open_paren = m.end() - 1
        close = matching(code, open_paren)
        if close < 0:
            continue
        brace = code.find("{", close)
        end = matching(code, brace) if brace >= 0 else -1
        if end < 0:
            continue
        body = code[brace:end]
        if not asserts(body, helpers):
            name = normalise(code[open_paren + 1:close])
            skip = " (skips only)" if "GTEST_SKIP" in body else ""
            findings.append((path, line_of(code, m.start()), "no-assertion",
                             "{} has no assertion{}".format(name, skip)))
    # A finding its line marks as intended (`// lint-tests: allow <kind>`) is dropped: for
    # tests of test helpers that must see the bad form.
    lines = raw.split("\n")
    return [f for f in findings
            if "lint-tests: allow " + f[2] not in lines[f[1] - 1]]


def test_files(paths):
    for path in paths:
        if os.path.isfile(path):
            yield path
            continue
        for root, dirs, files in os.walk(path):
            dirs[:] = sorted(d for d in dirs
                             if d not in SKIP_DIRS and not d.startswith("build"))
            for name in sorted(files):
                if name.endswith("_test.cc"):
                    yield os.path.join(root, name)


def shared_helper_names(repo):
    texts = []
    for name in ("test_support.h", "test_support.cc"):
        path = os.path.join(repo, "tests", name)
        if os.path.isfile(path):
            with open(path, encoding="utf-8") as f:
                texts.append(blank_comments(f.read(), keep_strings=False))
    return assertion_helpers(texts)


def lint(paths, repo):
    shared = shared_helper_names(repo)
    findings = []
    for path in test_files(paths):
        with open(path, encoding="utf-8") as f:
            findings.extend(lint_text(path, f.read(), shared))
    return findings


def self_test(directory, repo):
    """The findings in `directory` must be exactly the lines marked LINT-EXPECT."""
    expected = set()
    for path in test_files([directory]):
        with open(path, encoding="utf-8") as f:
            for number, line in enumerate(f, 1):
                m = re.search(r"//\s*LINT-EXPECT:\s*([\w-]+)", line)
                if m:
                    expected.add((path, number, m.group(1)))
    found = {(p, l, k) for p, l, k, _ in lint([directory], repo)}
    missed, extra = expected - found, found - expected
    for p, l, k in sorted(missed):
        print("{}:{}: not found: {}".format(p, l, k))
    for p, l, k in sorted(extra):
        print("{}:{}: unexpected finding: {}".format(p, l, k))
    if not expected:
        print("{}: no LINT-EXPECT marks".format(directory))
        return 1
    if missed or extra:
        return 1
    print("lint-tests self-test: {} planted findings found, no others".format(len(expected)))
    return 0


def main(argv):
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if len(argv) == 3 and argv[1] == "--self-test":
        return self_test(argv[2], repo)
    paths = argv[1:] or [repo]
    files = list(test_files(paths))
    findings = lint(paths, repo)
    for path, line, kind, text in findings:
        print("{}:{}: {}: {}".format(os.path.relpath(path), line, kind, text))
    if findings:
        print("lint-tests: {} finding(s) in {} test files".format(len(findings), len(files)))
        return 1
    print("lint-tests: {} test files, no test that cannot fail".format(len(files)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))

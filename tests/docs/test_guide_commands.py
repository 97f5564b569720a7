"""The guide works when pasted: every shell block of README.md and of docs/tutorials/*.md
runs, in order, against a live ``chizu serve`` on a fresh data directory, and what the
blocks show as output is what the commands print.

What a document may hold, and how each part is checked:

- A ``sh`` block is run by bash (``set -euo pipefail``: a failing command, an undefined
  variable or a failing stage of a pipe fails the test), in one shell per document, so a
  variable or function defined in one block is there in the next, as in a user's terminal.
  The working directory is a fresh folder that holds the repository's ``.venv``,
  ``examples`` and ``prolog`` (links), as a clone does; the data directory is its ``var``,
  ``chizu``'s default. ``curl`` fails on an HTTP error (``--fail-with-body``) unless the
  command asks for ``%{http_code}``, whose output then shows the status.
- Lines ``#> ...`` after commands are the output those commands print since the previous
  ``#>`` lines (stdout, ANSI colours removed, trailing blanks ignored). Without a marker it
  must match exactly. In a shown line ``...`` stands for any text, and a line that is only
  ``...`` for any number of lines. ``# output varies`` anywhere in the commands or the shown
  lines lets every number differ (timings, a pose to the last digit); ``# abridged`` lets
  the command print lines that are not shown, between and around the shown ones, which
  must still appear in their order.
- ``make TARGET`` lines are checked with ``make -n`` in the repository (the target exists
  and its recipe expands; running ``make test`` inside the tests is not possible).
- A ``chizu repl ...`` line is not run by bash: the ``prolog`` block right after it is a
  transcript of that REPL, driven in a pseudo-terminal as a user types it. A line
  ``?- Goal.`` is typed; after an answer, a line ending in `` ;`` means ``;`` was pressed
  and one ending in `` .`` means Enter (the copy REPL, swipl's toplevel). In the live REPL
  (``--live``) a line `` ;`` is ``;`` and Enter, an empty line Enter alone. The transcript
  must match as shown lines do (``% abridged`` / ``% output varies`` as markers).
- ``127.0.0.1:8000`` and ``localhost:8000`` are the test server's address (a free port).

Blocks in other languages (``csv``, ``json``, ``text``...) are not run. Relative links in
the documents must point at files that exist.
"""

from __future__ import annotations

import json
import os
import pty
import re
import select
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs" / "tutorials").glob("*.md"))]
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]|\x1b[()][A-Z0-9]|\x1b[=>]")
NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
FENCE = re.compile(r"^```(\w*)\s*(.*)$")
REPL = re.compile(r"^\s*(?:\S*/)?chizu\s+repl\b.*$")
MAKE = re.compile(r"^(\s*(?:[A-Z_][A-Z0-9_]*=\S*\s+)*)make\b(.*)$")
ADDRESSES = ("127.0.0.1:8000", "localhost:8000")
#: the whole of one document's commands (the README's tour runs in about two minutes)
DOC_TIMEOUT_S = 900


@dataclass
class Block:
    lang: str
    lines: list[str]
    line_no: int  # of the opening fence, 1-based


@dataclass
class Step:
    """A piece of a document to run: shell code, or a REPL transcript; with the output it
    shows (None: not checked beyond success)."""

    where: str
    code: str = ""
    shown: list[str] | None = None
    loose_numbers: bool = False
    abridged: bool = False
    repl: str | None = None  # the REPL command line of a transcript
    keys: list[str] = field(default_factory=list)


def blocks(text: str) -> list[Block]:
    out: list[Block] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        start, body = i, []
        i += 1
        while i < len(lines) and not lines[i].startswith("```"):
            body.append(lines[i])
            i += 1
        out.append(Block(m.group(1), body, start + 1))
        i += 1
    return out


def markers(text: str, comment: str) -> tuple[bool, bool]:
    return f"{comment} output varies" in text, f"{comment} abridged" in text


def shell_steps(block: Block, doc: str) -> tuple[list[Step], str | None]:
    """The block's steps, and the REPL command its last line opens (if it does)."""
    steps: list[Step] = []
    code: list[str] = []
    shown: list[str] = []
    repl: str | None = None

    def flush(end: int) -> None:
        nonlocal code, shown
        if not code and not shown:
            return
        text = "\n".join(code + shown)
        varies, abridged = markers(text, "#")
        steps.append(Step(f"{doc}:{end}", "\n".join(code), shown if shown else None,
                          varies, abridged))
        code, shown = [], []

    for k, line in enumerate(block.lines):
        no = block.line_no + 1 + k
        if line.startswith("#>"):
            shown.append(line[3:] if line.startswith("#> ") else line[2:])
            continue
        if shown:
            flush(no - 1)
        if REPL.match(line):
            if any(REPL.match(rest) or rest.strip() and not rest.lstrip().startswith("#")
                   for rest in block.lines[k + 1:]):
                raise AssertionError(f"{doc}:{no}: a REPL must be the block's last command")
            repl = line.split("#", 1)[0].strip()
            continue
        m = MAKE.match(line)
        if m is not None:
            line = f'{m.group(1)}make -n -C "$CHIZU_DOCS_ROOT"{m.group(2)} > /dev/null'
        code.append(line)
    flush(block.line_no + len(block.lines))
    return steps, repl


def transcript_step(block: Block, repl: str, doc: str) -> Step:
    """The keys a user typed to get the transcript, and the transcript to compare."""
    live = "--live" in repl.split()
    keys: list[str] = []
    lines = [ln for ln in block.lines if ln.strip() not in ("% output varies", "% abridged")]
    for ln in lines:
        if ln.startswith("?- "):
            keys.append(ln[3:] + "\n")
        elif live and ln.rstrip() == " ;":
            keys.append(";\n")
        elif live and ln.strip() == "" and keys:
            keys.append("\n")
        elif not live and ln.rstrip().endswith(" ;"):
            keys.append(";")
        elif not live and ln.rstrip().endswith(" ."):
            keys.append("\r")
    varies, abridged = markers("\n".join(block.lines), "%")
    return Step(f"{doc}:{block.line_no}", shown=lines, loose_numbers=varies,
                abridged=abridged, repl=repl, keys=keys)


def steps_of(path: Path) -> list[Step]:
    return steps_in(path.read_text(), str(path.relative_to(ROOT)))


def steps_in(text: str, doc: str) -> list[Step]:
    """The steps of a document's text (``doc`` names it in messages)."""
    out: list[Step] = []
    pending: str | None = None
    for b in blocks(text):
        if b.lang == "prolog" and pending is not None:
            out.append(transcript_step(b, pending, doc))
            pending = None
            continue
        if pending is not None:
            raise AssertionError(f"{doc}:{b.line_no}: `{pending}` is not followed by its "
                                 "transcript (a prolog block)")
        if b.lang in ("sh", "bash", "shell"):
            steps, pending = shell_steps(b, doc)
            out.extend(steps)
    if pending is not None:
        raise AssertionError(f"{doc}: `{pending}` is not followed by its transcript")
    return out


def local(text: str, port: int) -> str:
    for a in ADDRESSES:
        text = text.replace(a, a.replace("8000", str(port)))
    return text


def clean(text: str) -> str:
    text = ANSI.sub("", text).replace("\r\n", "\n").replace("\r", "")
    return "\n".join(ln.rstrip() for ln in text.split("\n")).strip("\n")


def pattern(shown: list[str], loose_numbers: bool, abridged: bool) -> re.Pattern[str]:
    """A regex for the whole output: ``...`` any text, a ``...`` line any lines, numbers
    any numbers when loose; abridged: any lines before, between and after."""
    parts: list[str] = []
    for ln in (s.rstrip() for s in shown):
        if ln.strip() == "...":
            parts.append(r"(?:[^\n]*\n)*?")
            continue
        pieces = []
        for piece in ln.split("..."):
            if loose_numbers:
                pieces.append("".join(
                    re.escape(t) if i % 2 == 0 else r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"
                    for i, t in enumerate(split_numbers(piece))))
            else:
                pieces.append(re.escape(piece))
        parts.append("[^\n]*?".join(pieces) + r"\n")
    glue = r"(?:[^\n]*\n)*?" if abridged else ""
    return re.compile(glue + glue.join(parts) + glue, re.S)


def split_numbers(piece: str) -> list[str]:
    """``piece`` cut at its numbers: text, number, text, ..., text."""
    out: list[str] = []
    pos = 0
    for m in NUMBER.finditer(piece):
        out += [piece[pos:m.start()], m.group(0)]
        pos = m.end()
    return out + [piece[pos:]]


def matches(step: Step, output: str) -> bool:
    assert step.shown is not None
    text = clean(output) + "\n"
    return pattern(step.shown, step.loose_numbers, step.abridged).fullmatch(text) is not None


# -- running the REPL transcripts in a pseudo-terminal ---------------------------------------
def drive(command: str, keys: list[str], cwd: str, quiet_s: float = 0.6,
          first_s: float = 60.0) -> str:
    """Run ``command`` in a pseudo-terminal, type ``keys`` one at a time (each after the
    output has settled), leave with ``halt.``; what the terminal showed."""
    pid, fd = pty.fork()
    if pid == 0:  # the child: the REPL, as a user's shell in a terminal emulator starts it
        os.chdir(cwd)
        os.execvpe("bash", ["bash", "-c", "exec " + command],
                   {**os.environ, "TERM": "xterm-256color"})
    out = bytearray()

    def settle(first: float) -> None:
        start = last = time.monotonic()
        got = False
        while True:
            ready, _, _ = select.select([fd], [], [], 0.05)
            if ready:
                try:
                    data = os.read(fd, 65536)
                except OSError:
                    return
                if not data:
                    return
                out.extend(data)
                got, last = True, time.monotonic()
            elif got and time.monotonic() - last > quiet_s:
                return
            elif not got and time.monotonic() - start > first:
                return

    try:
        settle(first_s)
        for k in keys:
            os.write(fd, k.encode())
            settle(30.0)
        os.write(fd, b"halt.\n")
        settle(10.0)
    finally:
        try:
            os.kill(pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        os.waitpid(pid, 0)
        os.close(fd)
    return out.decode(errors="replace")


def screen(raw: str) -> str:
    """The lines a terminal shows for ``raw``: carriage returns, cursor moves along the
    line (CSI n G / C / D), erasing (CSI K) and backspaces applied, colours dropped, as
    swipl's line editor redraws a line to flash the matching bracket."""
    lines: list[list[str]] = [[]]
    col = 0
    i = 0
    while i < len(raw):
        ch = raw[i]
        if ch == "\x1b":
            m = re.compile(r"\x1b\[([0-9;?]*)([A-Za-z])").match(raw, i)
            if m is None:
                i += 2
                continue
            n = int(m.group(1)) if m.group(1).isdigit() else 1
            row = lines[-1]
            if m.group(2) == "G":
                col = n - 1
            elif m.group(2) == "C":
                col += n
            elif m.group(2) == "D":
                col = max(0, col - n)
            elif m.group(2) == "K":
                del row[col:]
            i = m.end()
            continue
        if ch == "\r":
            col = 0
        elif ch == "\n":
            lines.append([])
            col = 0
        elif ch == "\b":
            col = max(0, col - 1)
        elif ch >= " ":
            row = lines[-1]
            row.extend(" " * (col - len(row)))
            if col < len(row):
                row[col] = ch
            else:
                row.append(ch)
            col += 1
        i += 1
    return "\n".join("".join(r).rstrip() for r in lines)


def transcript(raw: str) -> str:
    """From the first goal to the last answer (the banner and the closing halt cut)."""
    lines = screen(raw).split("\n")
    first = next((i for i, ln in enumerate(lines) if ln.startswith("?- ")), len(lines))
    lines = lines[first:]
    while lines and (lines[-1].startswith("?- halt") or lines[-1] in ("", "?-")):
        lines.pop()
    return "\n".join(lines)


def repl_main(spec_path: str) -> None:
    """``python test_guide_commands.py repl SPEC``: drive one transcript (bash calls this,
    so the REPL runs where the document's commands ran), print what it showed."""
    spec = json.loads(Path(spec_path).read_text())
    sys.stdout.write(transcript(drive(spec["command"], spec["keys"], os.getcwd())) + "\n")


# -- the test ---------------------------------------------------------------------------------
def script(steps: list[Step], out: Path, port: int) -> str:
    """One bash script for the document: each step's output to ``out/<k>.out``, a
    ``<k>.ok`` once it succeeded, its end time to ``out/times``; the first failure stops
    it."""
    lines = ["set -euo pipefail", f"echo start $(date +%s.%N) > {out}/times",
             'curl() { case "$*" in *"%{http_code}"*) command curl "$@" ;; '
             '*) command curl --fail-with-body "$@" ;; esac; }']
    for k, s in enumerate(steps):
        if s.repl is not None:
            spec = out / f"{k}.json"
            spec.write_text(json.dumps({"command": local(s.repl, port), "keys": s.keys}))
            code = (f'"$CHIZU_DOCS_PYTHON" {shlex.quote(str(Path(__file__)))} repl '
                    f"{shlex.quote(str(spec))}")
        else:
            code = local(s.code, port)
        lines += ["{ :", code, f"}} > {out}/{k}.out 2> {out}/{k}.err < /dev/null",
                  f"touch {out}/{k}.ok", f"echo {k} $(date +%s.%N) >> {out}/times"]
    return "\n".join(lines) + "\n"


def checkout(tmp: Path) -> Path:
    """A folder that looks like a clone after ``make install``: .venv, examples, prolog."""
    home = tmp / "clone"
    home.mkdir()
    venv = Path(sys.executable).parent.parent
    for name, target in ((".venv", venv), ("examples", ROOT / "examples"),
                         ("prolog", ROOT / "prolog")):
        (home / name).symlink_to(target)
    return home


def run_steps(steps: list[Step], home: Path, out: Path, port: int,
              server_log: Path | None = None) -> list[str]:
    """Run a document's steps in ``home`` against the service on ``port``; what went
    wrong: every shown output that differs, then the first step that failed (it ends the
    run), then the slowest steps."""
    out.mkdir()
    (out / "doc.sh").write_text(script(steps, out, port))
    env = {k: v for k, v in os.environ.items() if not k.startswith("CHIZU_")}
    env.update(HOME=str(out), COLUMNS="100", TERM="dumb", CHIZU_DOCS_ROOT=str(ROOT),
               CHIZU_DOCS_PYTHON=sys.executable)
    env.pop("PYTEST_XDIST_WORKER", None)
    proc = subprocess.run(["bash", str(out / "doc.sh")], cwd=home, env=env,
                          capture_output=True, text=True, timeout=DOC_TIMEOUT_S)
    problems: list[str] = []
    for k, s in enumerate(steps):
        got = (out / f"{k}.out").read_text() if (out / f"{k}.out").exists() else ""
        if not (out / f"{k}.ok").exists():
            err = (out / f"{k}.err").read_text() if (out / f"{k}.err").exists() else ""
            log = server_log.read_text()[-3000:] if server_log is not None else ""
            problems.append(f"{s.where}: failed (bash exit {proc.returncode})\n--- code\n"
                            f"{s.code or s.repl}\n--- stdout\n{got[-3000:]}\n--- stderr\n"
                            f"{err[-3000:]}\n--- server log\n{log}")
            break
        if s.shown is not None and not matches(s, got):
            problems.append(f"{s.where}: printed\n{clean(got)}\n--- shown\n"
                            + "\n".join(s.shown))
    if problems:
        times = [float(ln.split()[1]) for ln in (out / "times").read_text().splitlines()]
        slowest = sorted(((b - a, s.where) for a, b, s in zip(times, times[1:], steps,
                                                               strict=False)), reverse=True)
        problems.append("slowest steps: " + ", ".join(f"{w} {t:.1f} s"
                                                      for t, w in slowest[:5]))
    return problems


@pytest.mark.parametrize("doc", DOCS, ids=[str(d.relative_to(ROOT)) for d in DOCS])
def test_every_command_block_runs_and_shows_what_it_prints(
        doc: Path, tmp_path: Path, live_server_factory) -> None:  # type: ignore[no-untyped-def]
    steps = steps_of(doc)
    assert any(s.repl is None and s.code for s in steps), f"{doc.name} runs no command"
    home = checkout(tmp_path)
    server = live_server_factory(home / "var", demo=True)
    problems = run_steps(steps, home, tmp_path / "out", server.port, server.log_path)
    assert not problems, "\n\n".join(problems)


LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)\s]*)?\)")


@pytest.mark.parametrize("doc", [*DOCS, *sorted((ROOT / "docs" / "notes").glob("*.md")),
                                 ROOT / "examples" / "README.md"],
                         ids=lambda d: str(d.relative_to(ROOT)))
def test_relative_links_point_at_files(doc: Path) -> None:
    """Every relative link of the guide, the tutorials, the notes and the examples' README
    names a file of the repository (the results pages once ``make bench`` has written
    them: docs/results/ is generated)."""
    missing = []
    for target in LINK.findall(doc.read_text()):
        if re.match(r"^[a-z]+:", target):
            continue
        path = (doc.parent / target).resolve()
        generated = path.parent == (ROOT / "docs" / "results").resolve()
        if not path.exists() and not (generated and not path.parent.exists()):
            missing.append(target)
    assert not missing, f"{doc.relative_to(ROOT)} links to missing files: {missing}"


# -- the runner's own rules, so that a document cannot pass by fooling it --------------------
def test_the_matcher_holds_shown_output_to_what_was_printed() -> None:
    exact = Step("x", shown=['{"found":true,"path":["a","c"]}'])
    assert matches(exact, '{"found":true,"path":["a","c"]}\n')
    assert not matches(exact, '{"found":false,"path":[]}\n')
    assert not matches(exact, '{"found":true,"path":["a","c"]}\nmore\n')
    dots = Step("x", shown=['{"state": "z", ...}', "..."])
    assert matches(dots, '{"state": "z", "pose": 1}\nmore\nlines\n')
    assert not matches(dots, '{"state": "y", "pose": 1}\n')
    loose = Step("x", shown=["took 5.0 s, error 0.032 m"], loose_numbers=True)
    assert matches(loose, "took 12.3 s, error 0.031 m")
    assert not matches(loose, "took 12.3 s, error none")
    short = Step("x", shown=["b", "d"], abridged=True)
    assert matches(short, "a\nb\nc\nd\ne\n")
    assert not matches(short, "a\nd\nb\n")


def test_the_runner_reads_commands_outputs_and_transcripts() -> None:
    doc = ("```sh\nX=1\necho $X\n#> 1\necho 2.5 s   # output varies\n#> 3.1 s\n"
           "make test\n.venv/bin/chizu repl demo\n```\n```prolog\n?- lr(c1, L, R, P).\n"
           "L = c2,\nR = rs1b,\nP = 1.0 ;\nL = c3,\nR = x,\nP = 0.9 .\n```\n")
    steps = steps_in(doc, "probe.md")
    assert [s.shown for s in steps[:2]] == [["1"], ["3.1 s"]]
    assert not steps[0].loose_numbers and steps[1].loose_numbers
    assert "make -n" in steps[2].code and steps[2].shown is None
    assert steps[3].repl == ".venv/bin/chizu repl demo"
    assert steps[3].keys == ["lr(c1, L, R, P).\n", ";", "\r"]


def test_the_runner_finds_a_wrong_output_and_a_failing_command(tmp_path: Path) -> None:
    """A document whose shown output differs, and one whose command fails (an undefined
    variable, as ``$B`` was), are reported; a right one is not."""
    right = Step("right", code="X=2\necho $((X + 1))", shown=["3"])
    wrong = Step("wrong", code="echo 4", shown=["5"])
    undefined = Step("undefined", code="echo $B")
    after = Step("after", code="echo never", shown=["never"])
    home = tmp_path / "home"
    home.mkdir()
    problems = run_steps([right, wrong, undefined, after], home, tmp_path / "out", 1)
    assert problems[0].startswith("wrong: printed\n4\n")
    assert problems[1].startswith("undefined: failed")
    assert not any(p.startswith("after") or p.startswith("right") for p in problems)
    assert run_steps([right], home, tmp_path / "out2", 1) == []


if __name__ == "__main__" and sys.argv[1:2] == ["repl"]:
    repl_main(sys.argv[2])

"""Docs that cannot go stale (issue 38 item 4): every `uv run ...` command quoted in README.md
and docs/*.md (code blocks and inline code) is parsed by its own script's command line, in
process, and stopped there: a renamed or unknown flag fails here, not in a reader's shell.

How: the script runs as __main__ with `tyro.cli` wrapped so that a successful parse raises
`Parsed` before any work; a bad command line ends in SystemExit(2) as it would for a user
(`--help` exits 0 and counts as parsed). Placeholders a page writes for a value (`N`, `...`,
`[--optional flags]`) are filled in or dropped first. pytest commands are checked for the test
files they name, `uv run studies/NAME.py` (a pattern, not a command) and external tools
(`python -m rl_zoo3...`, `tensorboard`) for being installed."""

from __future__ import annotations

import contextlib
import importlib.util
import io
import re
import runpy
import shlex
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
UV_RUN = re.compile(r"^(?:\w+=\S+\s+)*uv run (.+)$")


class Parsed(Exception):
    """Raised in place of the script's work once its command line parsed."""


def quoted_commands(text: str) -> list[str]:
    """`uv run ...` lines of fenced code blocks (continuations joined, comments dropped) and
    inline code spans (which may wrap across lines), as the text after `uv run`."""
    found = []
    for block in re.findall(r"^```[^\n]*\n(.*?)^```", text, re.S | re.M):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            m = UV_RUN.match(" ".join(line.split(" #", 1)[0].split()))
            if m:
                found.append(m.group(1))
    prose = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    for span in re.findall(r"(?<!`)`([^`]+)`(?!`)", prose):
        m = UV_RUN.match(" ".join(span.split()))
        if m:
            found.append(m.group(1))
    return found


def words(command: str) -> list[str]:
    """The command's words, a shell's redirections and pipes cut, placeholders filled:
    `[--flag value]` keeps its flag unless it is a pattern (`[--env.* ...]`), `...` goes,
    `N` (a number) becomes 1."""
    command = re.split(r"\s(?:>|\||&&|2>)\s?", command)[0]
    command = re.sub(r"\[([^\]]*)\]", lambda m: "" if "*" in m.group(1) else m.group(1), command)
    return ["1" if w == "N" else w for w in shlex.split(command) if w != "..."]


def parse_only(script: Path, argv: list[str]) -> tuple[bool, str]:
    """Run ``script`` as __main__ far enough to parse ``argv``: (parsed, what it printed)."""
    import tyro

    real = tyro.cli

    def cli_then_stop(*args, **kwargs):
        real(*args, **kwargs)
        raise Parsed

    out = io.StringIO()
    old_argv, old_path = sys.argv, list(sys.path)
    sys.argv = [str(script), *argv]
    sys.path.insert(0, str(script.parent))
    tyro.cli = cli_then_stop
    try:
        with contextlib.redirect_stderr(out), contextlib.redirect_stdout(out):
            runpy.run_path(str(script), run_name="__main__")
        return False, "ran to the end without parsing a command line:\n" + out.getvalue()
    except Parsed:
        return True, out.getvalue()
    except SystemExit as exc:
        return exc.code in (0, None), out.getvalue()
    finally:
        tyro.cli = real
        sys.argv, sys.path[:] = old_argv, old_path


# Errors about an example path the page names (a run folder, a model) that this checkout lacks:
# the flag was read; its value is an example. Only when that path really is absent.
ABSENT_EXAMPLE = re.compile(
    r"error: --\S+ (\S+): not a run folder|error: (\S+) (?:does not exist|not found)")


def check(command: str) -> tuple[bool, str]:
    ok, said = _check(command)
    m = ABSENT_EXAMPLE.search(said)
    if not ok and m and not (ROOT / (m.group(1) or m.group(2))).exists():
        return True, said
    return ok, said


def _check(command: str) -> tuple[bool, str]:
    w = words(command)
    if w[0] == "pytest":
        missing = [a for a in w[1:] if a.startswith("tests/") and not (ROOT / a.split("::")[0]).exists()]
        return not missing, f"missing test files: {missing}"
    if w[0] == "python" and w[1] == "-m":
        return importlib.util.find_spec(w[2].split(".")[0]) is not None, f"{w[2]} not installed"
    if w[0] == "tensorboard":
        return shutil.which("tensorboard", path=str(Path(sys.executable).parent)) is not None, ""
    if w[0] == "studies/NAME.py":  # the layout page's pattern for every study script
        return True, ""
    script = ROOT / w[0]
    if not (script.suffix == ".py" and script.is_file()):
        return False, f"no script {w[0]}"
    return parse_only(script, w[1:])


ALL = sorted({(p.relative_to(ROOT).as_posix(), c) for p in PAGES
              for c in quoted_commands(p.read_text())})


def test_the_pages_quote_commands():
    assert len(ALL) > 50, ALL  # the extractor still finds the pages' commands


@pytest.mark.parametrize("page, command", ALL, ids=[f"{p}: {c[:60]}" for p, c in ALL])
def test_every_quoted_command_parses(page, command, monkeypatch):
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("MUJOCO_GL", "egl")
    ok, said = check(command)
    assert ok, f"{page}: `uv run {command}` no longer parses: {said.strip()[-600:]}"


@pytest.mark.parametrize("command", [
    "ikpd.py --seeds 0-99 --prefix ikpd --env.ik-clearance 0.02",  # the renamed flag of issue 38
    "train.py --bogus-flag 1",
    "studies/runs.py rank --studdy v5",
    "metrics.py --prefix-a ikpd --prefix-b eval --breakdwn",
])
def test_a_renamed_or_unknown_flag_fails_the_check(command, monkeypatch):
    monkeypatch.chdir(ROOT)
    ok, said = check(command)
    assert not ok and "error" in said.lower(), said


def test_the_extractor_reads_blocks_continuations_and_wrapped_inline_code():
    text = ("run `uv run eval.py --seed 3\n--prefix x` here\n```bash\nuv run train.py \\\n"
            "  --timesteps 5  # a comment\necho no\n```\n")
    assert quoted_commands(text) == ["train.py --timesteps 5", "eval.py --seed 3 --prefix x"]
    assert words("metrics.py --headline a b [--labels A B] > out.txt") == [
        "metrics.py", "--headline", "a", "b", "--labels", "A", "B"]

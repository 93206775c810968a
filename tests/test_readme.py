"""Every shell command of the README works as written.

The README's fenced ``sh`` blocks are read line by line (comments dropped). Each command must be
one this test knows (``CHECKED``): a command renamed or added in the README without a check here,
or a check whose command left the README, fails. Each ``borescan`` command is parsed by the real
argument parser with the README's own words; ``import-csv`` (on docs/import-csv.md's example),
``validate``, ``status``, ``trace`` and ``sql`` are also run, on a simulated scan and a constructed
catalog; the ``snakemake``
lines run as a dry run (``--unlock`` for real) on that scan's raw root; the ``make`` targets are
shown with ``make -n``.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT, SNAKEMAKE, workflow_env
from test_catalog import built  # noqa: F401 (the constructed catalog fixture, shared)

from borescan.cli import build_parser, main

README = ROOT / "README.md"
RAW = "/data/gauge-logs"
RESULTS = "/data/borescan"
BIN = Path(sys.executable).parent

#: every command of the README, and what this test does with it besides parsing it:
#: "run" runs it (exit 0), "parse" only parses it (it writes results or needs a full history)
CHECKED = {
    "make run": "make",
    "make test": "make",
    "export PATH=$PWD/.venv/bin:$PATH": "venv",
    # on docs/import-csv.md's example
    f"borescan import-csv EXPORT.csv --meta META.yaml --raw-root {RAW}": "run",
    f"borescan validate {RAW}": "run",
    f"snakemake --cores 2 --config raw_root={RAW} results_root={RESULTS}": "dry-run",
    f"borescan status --results {RESULTS}": "run",
    f'borescan sql --results {RESULTS} "SELECT night, scan_id, status, reason FROM scans '
    'ORDER BY night"': "run",
    f"borescan sql --results {RESULTS} --query suspect_measurements": "run",
    f"snakemake --unlock --config raw_root={RAW} results_root={RESULTS}": "unlock",
    f"borescan rebuild-catalog --results {RESULTS}": "parse",  # needs stage tables
    f"borescan recompute --from 2026-11-21 --results {RESULTS}": "parse",
    "borescan status": "run",
    "borescan status --as-of 2026-11-24 --format json": "run",
    "borescan trace N20261121-TRI01-MEAS-HSG1104": "trace",
    "borescan sql --list": "run",
    "borescan sql --query calibration_lifecycle": "run",
    'borescan sql "SELECT scan_id, feature, diameter_20_mm, expanded_u_diameter_20_mm, conformity '
    'FROM diameters" --format csv': "run",
    "borescan certificate CALIBRATION_ID": "parse",
}


def readme_commands() -> list[str]:
    """Return the README's shell commands: each line of a fenced ``sh`` block, without its comment."""
    blocks = re.findall(r"^```sh\n(.*?)^```", README.read_text(encoding="utf-8"), flags=re.S | re.M)
    commands = []
    for block in blocks:
        for line in block.splitlines():
            words = shlex.split(line, comments=True)
            if words:
                commands.append(shlex.join(words) if words[0] != "export" else " ".join(words))
    return commands


def _key(command: str) -> str:
    """Return ``command`` as :func:`readme_commands` writes it (one quoting)."""
    words = shlex.split(command)
    return shlex.join(words) if words[0] != "export" else " ".join(words)


def test_every_readme_command_is_checked_and_every_check_is_in_the_readme():
    have = readme_commands()
    known = {_key(c) for c in CHECKED}
    assert [c for c in have if c not in known] == [], "README commands without a check in CHECKED"
    assert sorted(known - set(have)) == [], "checked commands no longer in the README"
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 160  # a user guide, details in docs/


def test_every_docs_link_of_the_readme_exists():
    links = set(re.findall(r"`(docs/[\w.-]+\.md)`", README.read_text(encoding="utf-8")))
    assert {
        "docs/import-csv.md",
        "docs/configuration.md",
        "docs/migration.md",
        "docs/papers.md",
        "docs/operations.md",
        "docs/ENGINEERING.md",
    } <= links
    assert sorted(link for link in links if not (ROOT / link).is_file()) == []


@pytest.fixture()
def places(built, tmp_path, capsys, monkeypatch):  # noqa: F811
    """Return the README's folders mapped to the test's.

    Return the README's example folders mapped to a raw root with one simulated spindle scan and
    to the constructed catalog, which is also ``results/`` of the current folder (the README's
    default); the current folder holds docs/import-csv.md's example as EXPORT.csv and META.yaml.
    """
    res, _ = built
    raw = tmp_path / "readme_raw"  # make_history has its own raw/ here
    assert (
        main(
            [
                "simulate",
                "tri",
                "--raw-root",
                str(raw),
                "--truth-root",
                str(tmp_path / "truth"),
                "--scan-id",
                "T1",
            ]
        )
        == 0
    )
    monkeypatch.chdir(res.parent)
    example = (ROOT / "docs" / "import-csv.md").read_text(encoding="utf-8").split("## Example", 1)[1]
    csv_text, meta_text = re.findall(r"^```(?:yaml)?\n(.*?)^```", example, flags=re.S | re.M)[:2]
    Path("EXPORT.csv").write_text(csv_text, encoding="utf-8")
    Path("META.yaml").write_text(meta_text, encoding="utf-8")
    capsys.readouterr()
    return {RAW: str(raw), RESULTS: str(res)}


def _words(command: str, places: dict[str, str]) -> list[str]:
    """Return the command's words with the README's example folders replaced by the test's."""
    out = []
    for word in shlex.split(command):
        for readme_path, here in places.items():
            word = word.replace(readme_path, here)
        out.append(word)
    return out


@pytest.mark.parametrize("command", [c for c, how in CHECKED.items() if c.startswith("borescan ")])
def test_borescan_commands_parse_and_run(command, places, capsys):
    words = _words(command, places)[1:]
    build_parser().parse_args(words)  # an unknown command or option exits 2 here
    how = CHECKED[command]
    if how == "trace":  # the demo's part scan is not in the constructed catalog: one that is
        words = ["trace", "PART-7"]
    if how in ("run", "trace"):
        code = main(words)
        out = capsys.readouterr()
        assert code == 0, out.err
        assert out.out.strip(), "a README command that prints nothing"
        if words[0] == "import-csv":
            assert "scan=N20261121-TRI01-CAL-P1" in out.out
        if words[0] == "validate":
            assert "T1" in out.out or "1 scan" in out.out, out.out


def test_snakemake_commands(places, tmp_path):
    env = workflow_env(tmp_path)
    for command, how in CHECKED.items():
        if not command.startswith("snakemake "):
            continue
        words = _words(command, places)
        extra = ["--dry-run", "--quiet"] if how == "dry-run" else []
        proc = subprocess.run(
            [str(SNAKEMAKE), *words[1:], *extra],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 0, (command, proc.stderr[-2000:])


def test_make_targets_and_the_venv_line():
    for command, how in CHECKED.items():
        if how == "make":
            target = command.split()[1]
            proc = subprocess.run(
                ["make", "-n", target], cwd=ROOT, capture_output=True, text=True, timeout=60
            )
            assert proc.returncode == 0, proc.stderr
            assert ("pytest" in proc.stdout) == (target == "test")
            # make run runs the workflow; make test lints it (snakemake --lint) before pytest
            assert ("snakemake --cores" in proc.stdout) == (target == "run")
            assert ("snakemake --lint" in proc.stdout) == (target == "test")
    # the README's tools are the venv's: the commands it runs bare are in the venv's bin
    assert CHECKED["export PATH=$PWD/.venv/bin:$PATH"] == "venv"
    assert all((BIN / tool).is_file() for tool in ("borescan", "snakemake", "python"))

"""Issue 37 items 6 and 7: `status`, `trace`, `sql` and the config loader answer every user error in a
line or two (no traceback), and `sql` cannot write files, attach databases, install or load
extensions, or read files outside the catalog.
"""

from __future__ import annotations

import duckdb
import pytest
from test_catalog import built  # noqa: F401 (the constructed catalog fixture, shared)

from borescan.cli import main
from borescan.config import ConfigError, load_config


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize(
    "text, message",
    [
        (
            "calibration:\n  validity_days: abc\n",
            r"calibration\.validity_days: 'abc' is not allowed \(type 'integer'\)",
        ),
        (
            "calibration:\n  validity_days: -3\n",
            r"calibration\.validity_days: -3 is not allowed \(minimum 1\)",
        ),
        (
            "calibraton:\n  validity_days: 3\n",
            r"calibraton: unknown key \(known here: artifacts, calibration, ",
        ),
        ("signal:\n  filtr: median\n", r"signal\.filtr: unknown key \(known here: extrema_on, filter, "),
        ("a: [\n", r"not YAML"),
        ("- 1\n", r"a config is a mapping of keys, got list"),
    ],
)
def test_a_bad_config_is_one_line_naming_the_key(tmp_path, capsys, text, message):
    import re

    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(path)
    code, out, err = _run(capsys, "status", "--results", str(tmp_path), "--config", str(path))
    assert (code, out) == (2, "") and len(err.splitlines()) == 1 and "Traceback" not in err
    assert err.startswith(f"borescan status: {path}: ") and re.search(message, err)
    code, out, err = _run(capsys, "validate", str(tmp_path), "--config", str(path))
    assert code == 2 and len(err.splitlines()) == 1 and re.search(message, err)


def test_the_shipped_config_and_the_defaults_load():
    assert load_config("config/config.yaml")["calibration"]["validity_days"] == 30
    assert load_config()["calibration"]["min_revolutions"] == 5


@pytest.mark.parametrize("content", [b"", b"not a database at all" * 100])
@pytest.mark.parametrize("command", [["status"], ["trace", "PART-7"], ["sql", "SELECT * FROM scans"]])
def test_an_empty_or_corrupt_catalog_is_a_message(tmp_path, capsys, content, command):
    (tmp_path / "catalog.duckdb").write_bytes(content)
    code, out, err = _run(capsys, *command, "--results", str(tmp_path))
    assert (code, out) == (1, "") and len(err.splitlines()) == 1 and "Traceback" not in err
    assert "not a valid DuckDB database file" in err


@pytest.mark.parametrize("command", [["status"], ["trace", "PART-7"]])
def test_a_catalog_without_tables_is_a_message(tmp_path, capsys, command):
    duckdb.connect(str(tmp_path / "catalog.duckdb")).close()
    code, out, err = _run(capsys, *command, "--results", str(tmp_path))
    assert (code, out) == (1, "") and len(err.splitlines()) == 1
    assert f"the history catalog under {tmp_path} cannot be read (Catalog Error: Table with name" in err
    assert f"borescan rebuild-catalog --results {tmp_path}" in err


def test_sql_reads_the_catalog_and_nothing_else(built, tmp_path, capsys):  # noqa: F811
    res, _ = built
    folder = tmp_path / "outside"
    folder.mkdir()
    outside = folder / "outside.csv"
    outside.write_text("secret,value\nkey,42\n")
    code, out, _ = _run(
        capsys, "sql", "--results", str(res), "--format", "csv", "SELECT count(*) AS n FROM scans"
    )
    assert (code, out) == (0, "n\n11\n")
    refused = {
        "COPY": f"COPY scans TO '{folder / 'scans.csv'}'",
        "EXPORT": f"EXPORT DATABASE '{folder / 'export'}'",
        "ATTACH": f"ATTACH '{folder / 'other.duckdb'}' AS other",
        "INSTALL": "INSTALL httpfs",
        "LOAD": "LOAD httpfs",
        "read_csv": f"SELECT * FROM read_csv('{outside}')",
        "read_text": "SELECT * FROM read_text('/etc/hostname')",
        "glob": f"SELECT * FROM glob('{folder}/*')",
        "settings": "SET enable_external_access = true",
        "write": "CREATE TABLE x AS SELECT 1",
    }
    for what, sql in refused.items():
        code, out, err = _run(capsys, "sql", "--results", str(res), sql)
        assert code == 1 and out == "" and "Traceback" not in err, (what, err)
        assert "42" not in err and "secret" not in err, what
    assert sorted(p.name for p in folder.iterdir()) == ["outside.csv"]  # nothing written
    # the saved queries (views over the catalog) still run: PART-7 was measured with CAL-A, which failed later
    code, out, _ = _run(
        capsys, "sql", "--results", str(res), "--query", "suspect_measurements", "--format", "csv"
    )
    assert code == 0 and "PART-7" in out

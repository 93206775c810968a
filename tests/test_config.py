"""Config defaults live in one place, the schema; the shipped config agrees with it."""

import copy
from pathlib import Path

import pytest
import yaml
from snakemake.utils import validate

from borescan.config import SCHEMA_PATH, load_config, schema_defaults

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "config" / "config.yaml"


def _leaves(node, path=()):
    if node.get("type") == "object" and "properties" in node:
        for key, sub in node["properties"].items():
            yield from _leaves(sub, path + (key,))
    else:
        yield path, node


def _schema():
    return yaml.safe_load(SCHEMA_PATH.read_text())


def test_every_key_has_a_default_and_a_description():
    for path, node in _leaves(_schema()):
        assert "default" in node, f"{'.'.join(path)} has no default"
        assert node.get("description"), f"{'.'.join(path)} has no description"


def test_shipped_config_validates_and_holds_the_schema_defaults():
    cfg = yaml.safe_load(SHIPPED.read_text())
    validate(copy.deepcopy(cfg), str(SCHEMA_PATH))
    defaults = schema_defaults()

    def check(user, dflt, where):
        for k, v in user.items():
            assert k in dflt, f"{where}{k} is not in the schema"
            if isinstance(v, dict):
                check(v, dflt[k], f"{where}{k}.")
            else:
                assert v == dflt[k], (
                    f"{where}{k}: config/config.yaml says {v!r}, the schema's default is {dflt[k]!r}"
                )

    check(cfg, defaults, "")


@pytest.mark.parametrize(
    "user", [{}, "shipped", {"calibration": {"validity_days": 7}, "signal": {"filter": "gaussian"}}]
)
def test_load_config_fills_what_snakemake_validate_fills(user, tmp_path):
    user = yaml.safe_load(SHIPPED.read_text()) if user == "shipped" else user
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(user))
    snake = copy.deepcopy(user)
    validate(snake, str(SCHEMA_PATH), set_default=True)
    assert load_config(path) == snake


def test_unknown_or_removed_keys_are_refused():
    # measurement.sensor_noise_mm was never read; it is gone from the schema (README migration note)
    with pytest.raises(Exception, match="sensor_noise_mm"):
        validate({"measurement": {"sensor_noise_mm": 0.003}}, str(SCHEMA_PATH))


def test_a_removed_key_says_what_replaced_it():
    """stage_workers (a night job's processes) is the rules' threads now.

    The message says so, in one line, and a mistyped key beside it is still named.
    """
    from borescan.config import ConfigError, check_config

    with pytest.raises(ConfigError) as err:
        check_config({**load_config(), "stage_workers": 4, "stage_wrokers": 1}, "config")
    msg = str(err.value)
    assert "stage_workers: removed" in msg and "--set-threads <rule>=N" in msg
    assert "stage_wrokers: unknown key" in msg and "\n" not in msg


def test_shipped_device_model_validates_and_its_entries_parse():
    """config/devices.yaml (read by the Snakefile after config.yaml) holds only the devices section,
    valid against the schema, each entry a registry key the device model accepts.
    """
    from borescan.effects import device_model_effects

    devices = yaml.safe_load((SHIPPED.parent / "devices.yaml").read_text())
    assert set(devices) == {"devices"}
    validate(copy.deepcopy({**yaml.safe_load(SHIPPED.read_text()), **devices}), str(SCHEMA_PATH))
    assert device_model_effects(devices["devices"], "TRI-01", "2026-11-23") == ()
    assert device_model_effects(devices["devices"], "TRI-01", "2026-11-24") == ("channel_delay@2",)
    assert 'configfile: "config/devices.yaml"' in (SHIPPED.parent.parent / "Snakefile").read_text()


def test_library_defaults_are_the_schemas():
    """A keyword a caller leaves unset takes the schema's default (no copy of it in the code)."""
    from borescan.calibrate.result import AcceptanceRule
    from borescan.config import load_config, schema_default
    from borescan.discrepancy.terms import registry_terms

    cfg = load_config()
    assert AcceptanceRule.defaults() == AcceptanceRule.from_config(cfg["calibration"])
    assert AcceptanceRule.defaults(head_radius_mm=5.0).head_radius_mm == 5.0
    assert schema_default("uncertainty", "coverage_probability") == cfg["uncertainty"]["coverage_probability"]
    k_max = cfg["discrepancy"]["max_harmonic"]
    lobes = {t.k for t in registry_terms("tri_spindle", (1, 2, 3), have={}) if t.effect == "bore_lobing"}
    assert lobes == set(range(2, k_max + 1))
    with pytest.raises(KeyError, match="uncertainty.no_such_key"):
        schema_default("uncertainty", "no_such_key")


def test_the_shipped_schema_reads_the_same_on_either_yaml_loader_and_each_caller_gets_a_copy():
    """The schema is parsed on libyaml where PyYAML has it: the same objects as the pure-Python safe loader.

    The defaults a caller gets are its own: changing them changes no other caller's.
    """
    from borescan import config

    text = Path(SCHEMA_PATH).read_text()
    assert yaml.load(text, Loader=config._SCHEMA_LOADER) == yaml.safe_load(text)
    stated = yaml.safe_load(text)["properties"]["uncertainty"]["properties"]["coverage_probability"][
        "default"
    ]
    first = schema_defaults()
    first["uncertainty"]["coverage_probability"] = -1.0
    assert schema_defaults()["uncertainty"]["coverage_probability"] == stated

"""protocols/process.py: the signing-key sources and their order, and the flag set."""

import argparse
from pathlib import Path

import pytest

from protocols.process import add_signing_arguments, add_zenoh_arguments, signing_key_text
from protocols.signing import SIGNING_KEY_ENV


def _parse(argv):
    p = argparse.ArgumentParser()
    add_signing_arguments(p)
    add_zenoh_arguments(p, listen_default="none", connect_help="peers")
    return p.parse_args(argv)


def test_key_file_beats_flag_beats_environment(tmp_path):
    key_file = tmp_path / "key"
    key_file.write_text("from-file\n", encoding="utf-8")
    env = {SIGNING_KEY_ENV: "from-env"}
    argv = ["--signing-key-file", str(key_file), "--signing-key", "from-flag"]
    assert signing_key_text(_parse(argv), env) == "from-file\n"
    assert signing_key_text(_parse(["--signing-key", "from-flag"]), env) == "from-flag"
    assert signing_key_text(_parse([]), env) == "from-env"
    assert signing_key_text(_parse([]), {SIGNING_KEY_ENV: ""}) is None
    assert signing_key_text(_parse([]), {}) is None


def test_unreadable_key_file_is_an_os_error(tmp_path):
    with pytest.raises(OSError):
        signing_key_text(_parse(["--signing-key-file", str(tmp_path / "missing")]), {})


def test_zenoh_flags_repeat():
    args = _parse(["--zenoh-listen", "tcp/a:1", "--zenoh-listen", "tcp/b:2", "--zenoh-config", "z"])
    assert args.zenoh_listen == ["tcp/a:1", "tcp/b:2"]
    assert args.zenoh_connect == []
    assert args.zenoh_config == Path("z")

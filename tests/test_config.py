"""One configuration tree: defaults in code < a recording's metadata < a file < ``--set``; bad keys named."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.config import Config
from common.config_loading import load_config
from common.errors import ConfigError


def test_each_layer_overrides_the_one_before(tmp_path: Path) -> None:
    toml = tmp_path / "car.toml"
    toml.write_text("[voxel]\nedge = 0.3\n[tracker]\nghost_frames = 9\n")
    assert Config().voxel.edge == 0.25  # the paper's default
    assert load_config(base={"voxel": {"edge": 0.2}}).voxel.edge == 0.2
    assert load_config(toml, base={"voxel": {"edge": 0.2}}).voxel.edge == 0.3
    cfg = load_config(toml, ["voxel.edge=0.15"], base={"voxel": {"edge": 0.2}})
    assert cfg.voxel.edge == 0.15 and cfg.tracker.ghost_frames == 9  # --set wins, the rest of the file stays
    yaml_file = tmp_path / "car.yaml"
    yaml_file.write_text("voxel:\n  edge: 0.35\n")
    assert load_config(yaml_file).voxel.edge == 0.35


def test_unknown_keys_and_bad_files_are_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"voxel\.egde"):
        load_config(sets=["voxel.egde=0.2"])
    broken = tmp_path / "broken.toml"
    broken.write_text("[voxel\nedge = ")
    with pytest.raises(ConfigError, match=r"broken\.toml"):
        load_config(broken)
    with pytest.raises(ConfigError, match="key=value"):
        load_config(sets=["voxel.edge"])

"""read_model_info parses a file once per version of it: instances of a batch share the parse,
and an FMU replaced or rewritten at the same path is read again."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from bridge.fmu import read_model_info
from bridge.models import example_fmu


def test_the_same_file_is_parsed_once(tmp_path: Path) -> None:
    path = tmp_path / "model.fmu"
    shutil.copy(example_fmu("dcmotor"), path)
    assert read_model_info(path) is read_model_info(str(path))


def test_a_file_replaced_at_the_same_path_is_read_again(tmp_path: Path) -> None:
    path = tmp_path / "model.fmu"
    shutil.copy(example_fmu("dcmotor"), path)
    assert read_model_info(path).model_name == "dcmotor"
    other = tmp_path / "other.fmu"
    shutil.copy(example_fmu("feedthrough"), other)
    os.replace(other, path)  # a new export over the old one
    assert read_model_info(path).model_name == "feedthrough"
    shutil.copyfile(example_fmu("cartpole"), path)  # rewritten in place (same inode)
    assert read_model_info(path).model_name == "cartpole"

"""Settings own the coercion of values: a mapping becomes a validated settings object, text a list where a list is due."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import pytest

from optoenc.errors import ConfigError
from optoenc.settings import Settings, coerce, field_value, setting, to_dict


@dataclass
class Box(Settings):
    """A settings group with a fixed-length tuple, an open tuple, a list and a scalar."""

    size: tuple[int, int] = setting((3, 4), "rows, columns", ge=1)
    scales: tuple[float, ...] = setting((1.0,), "scales", gt=0)
    names: Optional[list[str]] = setting(None, "names")
    depth: float = setting(1.0, "depth", unit="m", gt=0)


def test_coerce_accepts_none_an_instance_or_a_mapping():
    assert coerce(Box, None, "box") == Box()
    b = Box(depth=2.0)
    assert coerce(Box, b, "box") is b
    assert coerce(Box, {"size": [5, 6]}, "box") == Box(size=(5, 6))


def test_coerce_errors_name_the_section_and_key():
    with pytest.raises(ConfigError) as err:
        coerce(Box, {"sise": [5, 6]}, "box")
    assert err.value.key == "box.sise" and "known: depth, names, scales, size" in str(err.value)
    with pytest.raises(ConfigError) as err:
        coerce(Box, {"depth": -1.0}, "box")
    assert err.value.key == "box.depth" and "> 0 m" in str(err.value)
    with pytest.raises(ConfigError, match="must be a Box or a mapping"):
        coerce(Box, 3, "box")


@pytest.mark.parametrize("text", ["5x6", "5 x 6", "5,6", "[5, 6]", "5 6"])
def test_a_fixed_length_tuple_reads_text(text):
    assert Box(size=text).size == (5, 6)
    assert field_value(Box, "size", text) == (5, 6)


def test_text_elements_take_the_element_type_and_lists_stay_lists():
    assert Box(scales="0.5,2").scales == (0.5, 2.0)
    assert Box(names="a,b").names == ["a", "b"]  # a list setting stays a list
    assert Box(size=[5, 6]).size == (5, 6)  # a list given for a tuple is held as the tuple its default is
    assert Box(**to_dict(Box(size=(7, 8)))) == Box(size=(7, 8))  # round trip through a plain mapping


def test_scalars_and_bad_text_are_left_to_validation():
    assert field_value(Box, "depth", "2") == "2"  # not a list setting: validate() judges the string
    with pytest.raises(ConfigError, match="must be a number, not str"):
        Box(depth="2")
    with pytest.raises(ConfigError) as err:
        Box(size="5xq")
    assert err.value.key == "size" and "written 24x32 or [24,32]" in str(err.value)
    with pytest.raises(ConfigError, match="must have 2 values, not 3"):
        Box(size="5x6x7")

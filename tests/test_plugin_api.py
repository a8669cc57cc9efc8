"""The public plugin API: one list of kinds, exported names, decoder shapes, mask plugins in a few lines."""

from __future__ import annotations

import pytest
import torch

import optoenc
from optoenc import hookspecs
from optoenc.registry import KINDS


def test_one_list_of_plugin_kinds_has_one_hook_each():
    assert list(hookspecs.HOOKS.values()) == list(KINDS)
    for hook in hookspecs.HOOKS:
        assert callable(getattr(hookspecs, hook)), f"no hook specification {hook}"

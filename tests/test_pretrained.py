"""The policies shipped in ``jaxnav/pretrained``: each loads (numpy, sha256 checked), is
small, and still meets the success its manifest states on fresh episodes."""

from __future__ import annotations

import math

import pytest

from jaxnav import pretrained
from jaxnav.pretrained.check import measure

FRESH_EPISODES = 200
FRESH_SEED = 31_337  # not the manifest's test episodes


@pytest.mark.parametrize("name", pretrained.names())
def test_shipped_policy_meets_its_stated_success(name):
    entry = pretrained.entry(name)
    policy = pretrained.load(name)
    assert policy.metadata["env_id"] == entry["env_id"]
    assert policy.metadata["env_kwargs"] == entry["env_kwargs"]
    assert pretrained.path(name).stat().st_size < 5 * 2**20  # small enough to ship
    stated = entry["measured"]
    assert stated["episodes"] >= 1000 and entry["commands"]
    got = measure(policy, FRESH_EPISODES, FRESH_SEED)
    p = stated["success_rate"]
    # 3 standard errors of a success rate over the fresh episodes (at least that of one
    # failure in them, so a stated 1.000 allows a few)
    margin = 3 * math.sqrt(max(p * (1 - p), 1 / FRESH_EPISODES) / FRESH_EPISODES)
    assert got["success_rate"] >= p - margin, (got, stated)


def test_names_and_errors():
    assert "gridmaze-dqn" in pretrained.names()
    with pytest.raises(ValueError, match="--pretrained nope: no such policy; shipped: "):
        pretrained.load("nope")

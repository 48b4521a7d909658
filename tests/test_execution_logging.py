"""``--backend dask`` keeps distributed's INFO chatter off stderr unless ``latticeopt -v``."""

from __future__ import annotations

import logging

import pytest

pytest.importorskip("distributed")

from latticeopt.execution import dask_client  # noqa: E402


@pytest.fixture
def root_level():
    root = logging.getLogger()
    saved = root.level, logging.getLogger("distributed").level

    def set_level(level):
        root.setLevel(level)
        logging.getLogger("distributed").setLevel(logging.INFO)  # as distributed configures itself on import

    yield set_level
    root.setLevel(saved[0])
    logging.getLogger("distributed").setLevel(saved[1])


@pytest.mark.parametrize("verbose", [False, True])
def test_distributed_loggers_follow_the_process_level(root_level, verbose):
    root_level(logging.INFO if verbose else logging.WARNING)
    with dask_client(1, None) as (_, threads):
        level = logging.getLogger("distributed").getEffectiveLevel()
        assert level == (logging.INFO if verbose else logging.WARNING)
        assert not logging.getLogger("distributed.scheduler").isEnabledFor(logging.INFO) or verbose
        assert threads == 1

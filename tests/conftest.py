"""Shared fixtures: one headless GL renderer per test session (EGL through Mesa on CI)."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

# Fuzz tests: no per-example deadline (shared 2-core machines are noisy); under CI the
# examples are derandomised so a run is repeatable (locally each run explores anew).
settings.register_profile("ci", derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if os.environ.get("CI") else "dev")


@pytest.fixture(scope="session")
def renderer():
    from splitrender.render import Renderer

    return Renderer()


@pytest.fixture(scope="session")
def gl(renderer):
    return renderer.ctx

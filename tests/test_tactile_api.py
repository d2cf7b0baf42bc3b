"""The tactile package's public API is what ``__all__`` declares."""

from __future__ import annotations

import univtac_data.generators.tactile as tactile


def test_all_names_exist_and_are_unique() -> None:
    assert len(set(tactile.__all__)) == len(tactile.__all__)
    for name in tactile.__all__:
        assert hasattr(tactile, name), name


def test_public_callables_are_exported() -> None:
    public = {n for n, v in vars(tactile).items() if not n.startswith("_") and callable(v) and
              getattr(v, "__module__", "").startswith("univtac_data.generators.tactile")}
    assert public <= set(tactile.__all__)

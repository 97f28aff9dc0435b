"""DBN-PHD with a model file loads it and never trains at start-up (issue 22)."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from pfscope.trackers.api import make_params, tracker_info  # noqa: E402
from pfscope.trackers.dbn import model as dbn_model  # noqa: E402
from pfscope.trackers.dbn.features import FeatureConfig  # noqa: E402


def test_a_model_file_is_loaded_not_trained(tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    d = FeatureConfig().dim
    y = (rng.random(200) < 0.4).astype(np.float64)
    X = np.clip(rng.random((200, d)) * 0.5 + 0.4 * y[:, None] * (np.arange(d) % 3 == 0), 0, 1)
    path = dbn_model.train_dbn(X, y, seed=0, pre_epochs=1, fine_epochs=2).save(tmp_path / "m.pt")
    dbn_model.default_model.cache_clear()

    def no_training(*a, **k):
        raise AssertionError("DBN-PHD trained a model although a model file was given")

    monkeypatch.setattr(dbn_model, "train_dbn", no_training)
    monkeypatch.setattr(dbn_model, "default_model", no_training)
    params = make_params("dbn-phd", None, {"dbn.model": str(path)})
    tr = tracker_info("dbn-phd").cls(params, rng=np.random.default_rng(0))
    assert tr.dbn is not None
    np.testing.assert_array_equal(tr.dbn.model.logits(X[:5]),
                                  dbn_model.load_model(path).logits(X[:5]))

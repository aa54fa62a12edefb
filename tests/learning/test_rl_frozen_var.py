"""A run's VAR is read from its checkpoint once, into one record: the frozen model, its path and the labels
it was trained on (2 per triplet, as the paper counts them)."""

import json
from pathlib import Path

import pytest
import torch

import learning.var.checkpoint
from learning.rl.frozen_var import LoadedVar, load_frozen_var
from learning.var.checkpoint import save_var
from learning.var.model import VAR, VARConfig


def test_the_var_is_read_once_and_frozen_with_its_triplet_labels_counted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    dataset = tmp_path / "triplets"
    dataset.mkdir()
    (dataset / "meta.json").write_text(json.dumps({"count": 150}))
    torch.manual_seed(0)
    trained = VAR(VARConfig(image_size=32)).train()
    path = save_var(trained, tmp_path / "var.pt", train_config={"dataset": str(dataset)})
    reads = []
    real_read = learning.var.checkpoint.read_checkpoint
    monkeypatch.setattr(learning.var.checkpoint, "read_checkpoint", lambda p: reads.append(p) or real_read(p))

    loaded = load_frozen_var(path)

    assert len(reads) == 1
    assert loaded.path == str(path) and loaded.image_size == 32 and loaded.embedding_dim == 3
    assert loaded.label_counts == {"var_triplet_labels": 300}
    assert not loaded.model.training
    assert not any(p.requires_grad for p in loaded.model.parameters())
    images = torch.randint(0, 256, (2, 32, 32, 3), dtype=torch.uint8)
    with torch.no_grad():
        assert torch.equal(loaded.model.encode_image(images), trained.eval().encode_image(images))


def test_a_var_without_a_known_dataset_counts_no_labels(tmp_path: Path) -> None:
    path = save_var(VAR(VARConfig(image_size=32)), tmp_path / "var.pt", train_config={"dataset": "gone"})
    assert load_frozen_var(path).label_counts == {}
    assert load_frozen_var(None) is None
    assert LoadedVar.in_memory(VAR(VARConfig(image_size=32)).train()).model.training is False

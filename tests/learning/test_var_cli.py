"""`varbot var ...` from the command line: the whole path on tiny data, and clear refusals of bad input."""

import json

import pytest
from typer.testing import CliRunner

from learning.sounds.build import build_corpora
from varbot.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def small_wordset() -> None:
    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)


def invoke(*arguments: str):
    result = runner.invoke(app, ["var", *arguments])
    return result, result.output


def test_collect_train_finetune_eval_and_plot_from_the_command_line(small_wordset, tmp_path) -> None:
    result, output = invoke(
        "collect", "kuka", "--triplets", "300", "--name", "cli-kuka", "--image-size", "32", "--workers", "1"
    )
    assert result.exit_code == 0, output
    assert "views/s" in output
    result, output = invoke(
        "train",
        "cli-kuka",
        "--run-dir",
        str(tmp_path / "run"),
        "--max-steps",
        "4",
        "--batch-size",
        "32",
        "--threads",
        "1",
        "--speed-copies",
        "1",
        "--room-copies",
        "1",
    )
    assert result.exit_code == 0, output
    checkpoint = tmp_path / "run" / "final.pt"
    assert checkpoint.is_file() and (tmp_path / "run" / "metrics.png").is_file()
    result, output = invoke(
        "finetune",
        str(checkpoint),
        "cli-kuka",
        "--splits",
        "unheard-real-voices",
        "--run-dir",
        str(tmp_path / "tuned"),
        "--epochs",
        "1",
        "--threads",
        "1",
    )
    assert result.exit_code == 0, output
    result, output = invoke(
        "finetune", str(checkpoint), "cli-kuka", "--front-end", "speech-embedding",
        "--run-dir", str(tmp_path / "refused"),
    )  # fmt: skip
    assert result.exit_code == 2, output
    assert "a VAR with the 'mfcc' sound front end and a fine-tune keeps its parent's" in output
    assert not (tmp_path / "refused").exists()
    result, output = invoke("eval", str(checkpoint), "cli-kuka", "--output", str(tmp_path / "eval.json"))
    assert result.exit_code == 0, output
    assert set(json.loads((tmp_path / "eval.json").read_text())["tiers"]) >= {
        "unheard-easy",
        "unheard-real-voices",
    }
    result, output = invoke("plot", str(checkpoint), "cli-kuka", "--output", str(tmp_path / "sphere.png"))
    assert result.exit_code == 0, output
    assert (tmp_path / "sphere.png").stat().st_size > 10_000


def test_bad_input_gets_a_clear_message_and_exit_code_2(small_wordset, tmp_path) -> None:
    result, output = invoke("collect", "mars", "--triplets", "10")
    assert result.exit_code == 2 and "Unknown world 'mars'" in output
    result, output = invoke("collect", "kuka", "--triplets", "10", "--heard-reach", "0.35")
    assert result.exit_code == 2 and "--heard-reach applies to the turtlebot world only" in output
    result, output = invoke("train", "no-such-dataset", "--sounds", "wordset")
    assert result.exit_code == 2 and "varbot var collect" in output
    result, output = invoke("train", "cli-kuka", "--speed-copies", "2", "--speed-range", "fast")
    assert result.exit_code == 2 and "--speed-range must be MIN,MAX" in output
    result, output = invoke("eval", str(tmp_path / "missing.pt"), "cli-kuka", "--sounds", "wordset")
    assert result.exit_code == 2 and "No VAR checkpoint" in output


def test_a_speech_embedding_var_trains_evaluates_and_plots_from_the_command_line(
    small_wordset, tmp_path
) -> None:
    result, output = invoke(
        "collect", "kuka", "--triplets", "300", "--name", "cli-kuka", "--image-size", "32", "--workers", "1"
    )
    assert result.exit_code == 0, output
    run = tmp_path / "embedding"
    result, output = invoke(
        "train", "cli-kuka", "--front-end", "speech-embedding", "--run-dir", str(run), "--max-steps", "4",
        "--batch-size", "32", "--threads", "1",
    )  # fmt: skip
    assert result.exit_code == 0, output
    result, output = invoke(
        "eval", str(run / "final.pt"), "cli-kuka", "--output", str(tmp_path / "eval.json")
    )
    assert result.exit_code == 0, output
    assert "unheard-real-voices" in json.loads((tmp_path / "eval.json").read_text())["tiers"]
    result, output = invoke(
        "plot", str(run / "final.pt"), "cli-kuka", "--output", str(tmp_path / "sphere.png")
    )
    assert result.exit_code == 0, output
    result, output = invoke("train", "cli-kuka", "--front-end", "wav2vec", "--run-dir", str(tmp_path / "bad"))
    assert result.exit_code == 2 and "Unknown sound front end 'wav2vec'" in output

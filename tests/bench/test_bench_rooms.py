"""bench/rooms.py can score a base model on the household bench's own voices: a synthesised household is
the first takes of a few of the tier's speakers, chosen by its seed, and the rooms bench reads exactly those
clips, featurised as the product featurises an uploaded recording."""

import json
from pathlib import Path

import household
import numpy as np
import rooms

from learning.audio import features_from_bytes
from learning.sounds import SoundCorpus, load_corpus
from learning.sounds.build import build_corpora
from worker.base_models import SHIPPED_DIR


def _corpus(speakers: int, intents: int, takes: int) -> SoundCorpus:
    rows = [(f"s{s}", i, t) for s in range(speakers) for i in range(intents) for t in range(takes)]
    return SoundCorpus(
        name="toy", kind="speech", features=np.zeros((len(rows), 2, 2), np.float32),
        intent=np.array([i for _, i, _ in rows], np.int64), speaker=np.array([s for s, _, _ in rows]),
        split=np.array(["unheard-real-voices"] * len(rows)),
        clip=np.array([f"{s}-{i}-{t}" for s, i, t in rows]), intent_names=[f"c{i}" for i in range(intents)],
        manifest_hash="",
    )  # fmt: skip


def test_a_synthesised_household_is_the_first_takes_of_a_few_speakers_chosen_by_its_seed() -> None:
    corpus = _corpus(speakers=6, intents=4, takes=3)
    rows = household.household_rows(corpus, members=3, clips_per_command=2, seed=0)
    picked = [str(corpus.clip[row]) for row in rows]
    speakers = sorted({clip.split("-")[0] for clip in picked})
    assert len(rows) == 3 * 4 * 2 and len(speakers) == 3
    assert {clip.split("-")[2] for clip in picked} == {"0", "1"}  # the first two takes, never the third
    assert household.household_rows(corpus, 3, 2, seed=0) == rows
    others = {
        str(corpus.speaker[row])
        for seed in range(1, 6)
        for row in household.household_rows(corpus, 3, 2, seed)
    }
    assert others != set(speakers), "another seed, another family"


def test_the_rooms_bench_scores_on_the_household_benchs_clips_as_the_product_reads_them(
    tmp_path: Path,
) -> None:
    build_corpora(["wordset"], profile="small", progress=False, log=lambda _: None)
    front_end = json.loads((SHIPPED_DIR / "kuka" / "base.json").read_text())["front_end"]
    # the small corpus's train split has six speakers: a family of three is half of it
    recordings, _ = household.synthesised_recordings(
        "wordset", "train", household.MEMBERS, household.CLIPS_PER_COMMAND, seed=0
    )
    goals = rooms.household_goals(0)("wordset", "train", front_end)
    assert len(goals.features) == len(recordings) == 24 < len(load_corpus("wordset").subset("train"))
    uploaded = np.stack([features_from_bytes(r.wav, "speech", front_end) for r in recordings])
    np.testing.assert_allclose(goals.features, uploaded, atol=1e-5)
    assert goals.intents.tolist() == [r.intent for r in recordings]

    out = tmp_path / "rooms.json"
    argv = ["--tag", "household", "--household-voices", "0", "--rooms", "training", "--splits",
            "unheard-real-voices", "--episodes-per-intent", "1", "--out", str(out)]  # fmt: skip
    rooms.main(argv)
    entry = json.loads(out.read_text())["entries"]["household"]
    assert entry["goal_clips"].startswith("the household bench's family of seed 0")
    assert entry["cells"]["training"]["unheard-real-voices"]["episodes"] == 4

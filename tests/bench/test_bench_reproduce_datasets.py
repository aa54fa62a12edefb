"""bench/reproduce.py names the views behind a row's VAR by what was collected, and the VAR by how it was
trained, so a VAR made from other views or with other options is never taken for the row's own."""

from argparse import Namespace

from reproduce import row_dataset, var_name


def arguments(**given) -> Namespace:
    defaults = {
        "var_dataset": None, "triplets": 50_000, "var_heard_reach": None, "var_max_steps": None,
        "var_speed_copies": 0, "var_room_copies": 0, "var_voice_copies": 0, "var_front_end": "mfcc",
    }  # fmt: skip
    return Namespace(**{**defaults, **given})


def test_the_default_views_keep_the_name_earlier_runs_made_them_under():
    assert row_dataset("turtlebot", arguments()) == "reproduce-turtlebot-50000"


def test_views_named_within_a_tighter_reach_are_their_own_dataset():
    assert row_dataset("turtlebot", arguments(var_heard_reach=0.35)) == "reproduce-turtlebot-50000-reach35cm"


def test_a_named_dataset_is_used_as_given():
    assert row_dataset("kuka", arguments(var_dataset="mine", var_heard_reach=0.35)) == "mine"


def test_a_var_with_default_options_keeps_the_name_earlier_runs_made_it_under():
    given = arguments(var_max_steps=4800, var_speed_copies=4)
    assert var_name("turtlebot", "objects", given) == "reproduce-turtlebot-50000-objects-4800steps-speed4"


def test_every_training_option_that_differs_from_the_default_is_in_the_var_name():
    given = arguments(var_heard_reach=0.35, var_max_steps=4800, var_speed_copies=4, var_room_copies=2,
                      var_voice_copies=2, var_front_end="speech-embedding")  # fmt: skip
    assert var_name("turtlebot", "objects", given) == (
        "reproduce-turtlebot-50000-reach35cm-objects-4800steps-speed4-rooms2-voices2-speech-embedding"
    )

"""bench/reproduce.py names the views behind a row's VAR by what was collected, so a VAR made from other
views is never taken for the row's own."""

from argparse import Namespace

from reproduce import row_dataset


def arguments(**given) -> Namespace:
    return Namespace(**{"var_dataset": None, "triplets": 50_000, "var_heard_reach": None, **given})


def test_the_default_views_keep_the_name_earlier_runs_made_them_under():
    assert row_dataset("turtlebot", arguments()) == "reproduce-turtlebot-50000"


def test_views_named_within_a_tighter_reach_are_their_own_dataset():
    assert row_dataset("turtlebot", arguments(var_heard_reach=0.35)) == "reproduce-turtlebot-50000-reach35cm"


def test_a_named_dataset_is_used_as_given():
    assert row_dataset("kuka", arguments(var_dataset="mine", var_heard_reach=0.35)) == "mine"

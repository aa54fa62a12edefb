"""NAME=VALUE settings as a command line gives them: JSON values where they are JSON, text otherwise."""

import pytest

from core.plain import name_value


def test_a_value_is_read_as_json_where_it_is_json_and_kept_as_text_otherwise() -> None:
    assert name_value("reward_temperature=0.25") == ("reward_temperature", 0.25)
    assert name_value("goal_match=true") == ("goal_match", True)
    assert name_value("target_intents=[0, 2]") == ("target_intents", [0, 2])
    assert name_value("policy_view=var") == ("policy_view", "var")
    assert name_value("note=a=b") == ("note", "a=b")


@pytest.mark.parametrize("text", ["policy_view", "=var", ""])
def test_text_without_a_name_and_an_equals_sign_is_refused(text: str) -> None:
    with pytest.raises(ValueError, match="write it as NAME=VALUE"):
        name_value(text)

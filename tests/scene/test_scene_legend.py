"""The sphere's legend says what each colour and marker means in the household's own command words, in the
very colours the sphere draws, and never lets a command's name into the page as markup."""

from scene.legend import NO_COMMANDS, legend_html
from scene.sphere import CURRENT_COLOUR, GOAL_COLOUR, UNASSIGNED, colour_of


def rgb(colour: tuple[int, int, int]) -> str:
    return "rgb({},{},{})".format(*colour)


def test_each_command_is_named_in_the_colour_its_points_have_on_the_sphere() -> None:
    commands = ["name:the cube", "name:zero", "clip:7"]
    legend = legend_html(commands)
    for command, words in zip(commands, ["“the cube”", "“zero”", "“recording 7”"], strict=True):
        assert words in legend
        swatch_then_words = legend.split(words)[0].rsplit("<li", 1)[1]
        assert rgb(colour_of(command, commands)) in swatch_then_words, f"{words} in its sphere colour"


def test_the_markers_and_shapes_are_explained() -> None:
    legend = legend_html(["name:zero"])
    assert rgb(UNASSIGNED) in legend and "closest to none of your commands" in legend
    assert rgb(CURRENT_COLOUR) in legend and "the robot's view right now" in legend
    assert rgb(GOAL_COLOUR) in legend and "the command it is carrying out" in legend
    assert "views the robot saw" in legend and "diamonds: your recordings" in legend


def test_a_household_without_commands_is_told_how_they_appear() -> None:
    assert NO_COMMANDS in legend_html([])


def test_a_commands_name_is_shown_as_text_not_markup() -> None:
    legend = legend_html(["name:<img src=x onerror=alert(1)>"])
    assert "<img" not in legend and "&lt;img src=x onerror=alert(1)&gt;" in legend

"""The sphere's legend in the panel: what each colour and marker on the embedding sphere means, in the
household's own command words (the colours are the sphere's, `scene.sphere.colour_of`)."""

from html import escape

import viser

from scene.sphere import CURRENT_COLOUR, GOAL_COLOUR, UNASSIGNED, colour_of, command_title

NO_COMMANDS = "No commands recorded yet: each command gets a colour here once it has a recording."


def _swatch(colour: tuple[int, int, int], shape: str) -> str:
    red, green, blue = colour
    radius = "50%" if shape == "circle" else "2px"
    turn = "transform:rotate(45deg);" if shape == "diamond" else ""
    return (
        f'<span style="display:inline-block;width:0.8em;height:0.8em;margin-right:0.4em;{turn}'
        f'border-radius:{radius};border:1px solid #555;background:rgb({red},{green},{blue})"></span>'
    )


def _row(swatch: str, words: str) -> str:
    return f'<li style="list-style:none;margin:0.15em 0">{swatch}{words}</li>'


def legend_html(commands: list[str]) -> str:
    """The legend for the household's commands (command keys, as `HouseholdView.commands` lists them)."""
    rows = [
        _row(_swatch(colour_of(c, commands), "square"), f"“{escape(command_title(c))}”") for c in commands
    ]
    if not rows:
        rows = [_row("", escape(NO_COMMANDS))]
    rows += [
        _row(_swatch(UNASSIGNED, "square"), "closest to none of your commands"),
        _row(
            _swatch((200, 200, 200), "circle"),
            "small dots: views the robot saw, in the colour of the command they are closest to",
        ),
        _row(_swatch((200, 200, 200), "diamond"), "diamonds: your recordings of each command"),
        _row(_swatch(CURRENT_COLOUR, "circle"), "white ball: where the robot's view right now lands"),
        _row(
            _swatch(GOAL_COLOUR, "circle"), "yellow ball: the command it is carrying out (or the one chosen)"
        ),
    ]
    return (
        '<div class="varbot-legend" style="font-size:0.85em">'
        '<p style="margin:0 0 0.3em">Colours are your commands; the closer two points, the more alike the '
        f'model finds them.</p><ul style="padding:0;margin:0">{"".join(rows)}</ul></div>'
    )


class SphereLegend:
    """The legend's folder in the panel, just below `after` (the status line), so that it is seen without
    scrolling the panel; redrawn only when the household's commands change."""

    def __init__(self, gui: viser.GuiApi, after: viser.GuiMarkdownHandle) -> None:
        with gui.add_folder("What the sphere shows", order=after.order + 0.5):
            self.html = gui.add_html(legend_html([]))
        self.commands: list[str] = []

    def show(self, commands: list[str]) -> None:
        if commands != self.commands:
            self.commands = list(commands)
            self.html.content = legend_html(self.commands)

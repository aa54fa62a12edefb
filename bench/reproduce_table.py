"""Table I from the stored records of bench/results/reproduce.json. Each line is one recipe (a row's or an
experiment's: every setting alike but the seed); its success is the mean and the spread (sample standard
deviation) over that recipe's complete seeds (over its partial ones when none is complete), and every seed's
own result is listed beside it. The figures printed are the ones stored under "table"."""

import json
import statistics

from result_files import relative_paths
from rich.console import Console
from rich.table import Table

NOT_RECIPE = {"seed", "torch_threads", "checkpoint_every"}  # settings that do not change what is learned
SEED_SOURCES = ("rows", "experiments", "earlier_runs")  # where a recipe's other seeds may be stored
# Settings added after runs were stored, each with the value that trains what a run from before it trained.
AS_BEFORE = {
    "replay_envs": 0,
    "room": "training",
    "reward_against_others": False,
    "policy_colour_jitter": 0.0,
    "policy_hue_turn": 0.0,
    "policy_view_shift": 0,
    "contact": "stop",  # the TurtleBot arena's own rule
    "hard_start_share": 0.0,
    "policy_view": "pixels",
    "policy_view_follows_var": False,
}
DATA_DIR_PREFIXES = ("$VARBOT_DATA_DIR/", "data/")  # a data directory elsewhere, or the default one


def learned_settings(config: dict) -> dict:
    """The settings that change what is learned; None ones are the same as missing ones (older runs stored
    the defaults of their day as None), and so are `AS_BEFORE` values; the replay room without replay envs."""
    settings = {k: v for k, v in config.items() if k not in NOT_RECIPE and v is not None}
    settings = {k: v for k, v in settings.items() if AS_BEFORE.get(k, object()) != v}
    if "replay_envs" not in settings:
        settings.pop("replay_room", None)
    return settings


def var_in_its_data_dir(checkpoint: str | None) -> str | None:
    """A VAR checkpoint by its place inside whichever data directory it was made in: one VAR recipe built in
    two data directories (after a machine was lost) is one VAR."""
    checkpoint = relative_paths(checkpoint)
    for prefix in DATA_DIR_PREFIXES:
        if checkpoint and checkpoint.startswith(prefix):
            return checkpoint.removeprefix(prefix)
    return checkpoint


def recipe(record: dict) -> str:
    """What a run trained, apart from its seed (`learned_settings`). What the reward paid is part of it
    (`REWARD_REVISIONS`)."""
    config = learned_settings(record.get("config") or {})
    same = {
        "row": record["row"],
        "method": record["method"],
        "var": var_in_its_data_dir(record.get("var_checkpoint")),
        "reward_revision": int(record.get("reward_revision", 1)),
    }
    return json.dumps(relative_paths({**same, "config": config}), sort_keys=True)


def evaluated_records(results: dict) -> list[tuple[str, dict]]:
    """(id, record) of every evaluated run, in the order a recipe's seeds are taken: rows first."""
    found = []
    for section in SEED_SOURCES:
        entries = results.get(section, {})
        pairs = entries.items() if isinstance(entries, dict) else enumerate(entries)
        found += [(f"{section}/{key}", r) for key, r in pairs if "success" in r and "config" in r]
    return found


def seeds_of(head: dict, evaluated: list[tuple[str, dict]]) -> list[dict]:
    """Every seed of the head record's recipe, one run per seed: the first complete one found, else the first
    found. The mean takes the complete seeds when there are any (`in_mean`), else the partial ones."""
    wanted, seeds = recipe(head), {}
    for record_id, record in evaluated:
        seed = record["config"].get("seed")
        if recipe(record) != wanted or seeds.get(seed, {}).get("status") == "complete":
            continue
        if seed not in seeds or record["status"] == "complete":
            seeds[seed] = {
                "seed": seed,
                "tag": record["tag"],
                "status": record["status"],
                "record": record_id,
                "env_steps": record["env_steps"],
                "success": record["success"],
            }
    any_complete = any(s["status"] == "complete" for s in seeds.values())
    for seed in seeds.values():
        seed["in_mean"] = seed["status"] == "complete" or not any_complete
    return sorted(seeds.values(), key=lambda s: (s["seed"] is None, s["seed"]))


def spread_over(seeds: list[dict]) -> tuple[dict, dict]:
    counted = [s for s in seeds if s["in_mean"]]
    tiers = dict.fromkeys(tier for s in counted for tier in s["success"])
    by_tier = {tier: [s["success"][tier] for s in counted if tier in s["success"]] for tier in tiers}
    means = {tier: statistics.fmean(values) for tier, values in by_tier.items()}
    spreads = {tier: statistics.stdev(v) if len(v) > 1 else None for tier, v in by_tier.items()}
    return means, spreads


def table_lines(results: dict) -> list[dict]:
    """One line per recipe, headed by its row's record (or, for a recipe no row has, its first experiment)."""
    evaluated = evaluated_records(results)
    heads = [("row", r) for r in results.get("rows", {}).values()]
    heads += [("experiment", r) for r in results.get("experiments", {}).values()]
    lines, recipes_done = [], set()
    for kind, head in heads:
        if "success" not in head or "config" not in head or recipe(head) in recipes_done:
            continue
        recipes_done.add(recipe(head))
        seeds = seeds_of(head, evaluated)
        means, spreads = spread_over(seeds)
        lines.append(
            {
                "row": head["row"],
                "method": head["method"],
                "kind": kind,
                "tag": head["tag"],
                "seeds": seeds,
                "seeds_in_mean": sum(s["in_mean"] for s in seeds),
                "success_mean": means,
                "success_spread": spreads,
                "paper_success": head.get("paper_success"),
                "labels": head["labels"]["total"],
            }
        )
    return lines


def percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f}"


def seed_cell(seed: dict) -> str:
    partial = "" if seed["status"] == "complete" else f", {seed['status']} at {seed['env_steps']:,}"
    partial += "" if seed["in_mean"] else ", not in the mean"
    tiers = " / ".join(percent(v) for v in seed["success"].values())
    return f"seed {seed['seed']} ({seed['tag']}{partial}): {tiers}"


def print_table(results: dict) -> None:
    """Prints the table and stores its figures under results["table"]."""
    lines = table_lines(results)
    results["table"] = {"spread": "sample standard deviation over seeds (none for one seed)", "lines": lines}
    table = Table(title="Table I on this machine (success %, unheard tiers: mean ± spread over seeds)")
    for column in ("row", "method", "seeds in the mean", "success by tier", "every seed", "paper", "labels"):
        table.add_column(column)
    for line in lines:
        label = line["row"] if line["kind"] == "row" else f"{line['row']} (experiment {line['tag']})"
        tiers = [
            f"{tier}: {percent(mean)}" + ("" if line["success_spread"][tier] is None else
                                          f" ± {percent(line['success_spread'][tier])}")
            for tier, mean in line["success_mean"].items()
        ]  # fmt: skip
        table.add_row(
            label, line["method"], f"{line['seeds_in_mean']} of {len(line['seeds'])}", "\n".join(tiers),
            "\n".join(seed_cell(s) for s in line["seeds"]), str(line["paper_success"]), f"{line['labels']:,}",
        )  # fmt: skip
    Console(width=200).print(table)

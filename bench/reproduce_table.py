"""Table I from the stored records of bench/results/reproduce.json. Each line is one recipe (a row's or an
experiment's: every setting alike but the seed); its success is the mean and the spread (sample standard
deviation) over that recipe's seeds, and every seed's own result is listed beside it. The figures printed are
the ones stored under "table"."""

import json
import statistics

from result_files import relative_paths
from rich.console import Console
from rich.table import Table

NOT_RECIPE = {"seed", "torch_threads", "checkpoint_every"}  # settings that do not change what is learned
SEED_SOURCES = ("rows", "experiments", "earlier_runs")  # where a recipe's other seeds may be stored


def recipe(record: dict) -> str:
    """What a run trained, apart from its seed; None settings are the same as missing ones (older runs
    stored the defaults of their day as None). What the reward paid is part of it (`REWARD_REVISIONS`)."""
    config = {k: v for k, v in (record.get("config") or {}).items() if k not in NOT_RECIPE and v is not None}
    same = {
        "row": record["row"],
        "method": record["method"],
        "var": record.get("var_checkpoint"),
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
    """Every seed of the head record's recipe, one run per seed (the first found)."""
    wanted, seeds = recipe(head), {}
    for record_id, record in evaluated:
        seed = record["config"].get("seed")
        if recipe(record) == wanted and seed not in seeds:
            seeds[seed] = {
                "seed": seed,
                "tag": record["tag"],
                "status": record["status"],
                "record": record_id,
                "env_steps": record["env_steps"],
                "success": record["success"],
            }
    return sorted(seeds.values(), key=lambda s: (s["seed"] is None, s["seed"]))


def spread_over(seeds: list[dict]) -> tuple[dict, dict]:
    tiers = dict.fromkeys(tier for s in seeds for tier in s["success"])
    by_tier = {tier: [s["success"][tier] for s in seeds if tier in s["success"]] for tier in tiers}
    means = {tier: statistics.fmean(values) for tier, values in by_tier.items()}
    spreads = {tier: statistics.stdev(v) if len(v) > 1 else None for tier, v in by_tier.items()}
    return means, spreads


def table_lines(results: dict) -> list[dict]:
    evaluated = evaluated_records(results)
    heads = [("row", r) for r in results.get("rows", {}).values()]
    heads += [("experiment", r) for r in results.get("experiments", {}).values()]
    lines = []
    for kind, head in heads:
        if "success" not in head or "config" not in head:
            continue
        seeds = seeds_of(head, evaluated)
        means, spreads = spread_over(seeds)
        lines.append(
            {
                "row": head["row"],
                "method": head["method"],
                "kind": kind,
                "tag": head["tag"],
                "seeds": seeds,
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
    tiers = " / ".join(percent(v) for v in seed["success"].values())
    return f"seed {seed['seed']} ({seed['tag']}{partial}): {tiers}"


def print_table(results: dict) -> None:
    """Prints the table and stores its figures under results["table"]."""
    lines = table_lines(results)
    results["table"] = {"spread": "sample standard deviation over seeds (none for one seed)", "lines": lines}
    table = Table(title="Table I on this machine (success %, unheard tiers: mean ± spread over seeds)")
    for column in ("row", "method", "seeds", "success by tier", "every seed", "paper", "labels"):
        table.add_column(column)
    for line in lines:
        label = line["row"] if line["kind"] == "row" else f"{line['row']} (experiment {line['tag']})"
        tiers = [
            f"{tier}: {percent(mean)}" + ("" if line["success_spread"][tier] is None else
                                          f" ± {percent(line['success_spread'][tier])}")
            for tier, mean in line["success_mean"].items()
        ]  # fmt: skip
        table.add_row(
            label, line["method"], str(len(line["seeds"])), "\n".join(tiers),
            "\n".join(seed_cell(s) for s in line["seeds"]), str(line["paper_success"]), f"{line['labels']:,}",
        )  # fmt: skip
    Console(width=200).print(table)

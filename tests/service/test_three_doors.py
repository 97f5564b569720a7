"""One knowledge base, three doors: POST /worlds/{w}/query, ``chizu repl --live`` (which
asks the same operation) and the copy REPL ``chizu repl W`` (a swipl with the world's
facts). The copy REPL defines every relation the query allows, by the same name and
arity, and the same goals answer alike at each door."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from fastapi.testclient import TestClient

from chizu.service.live_repl import LiveRepl
from tests.conftest import ROOT

#: goals answered with one number (the demo world holds landmarks, observations and
#: their relations, a DRM; no SLAM map, eigenspace or plan: those count 0 at each door)
COUNTS = [
    "aggregate_all(count, landmark(_), N)",
    "aggregate_all(count, rec(_, _, _), N)",
    "aggregate_all(count, frec(_, _, _), N)",
    "aggregate_all(count, lr(_, _, _, _), N)",
    "aggregate_all(count, align(_, _, _, _, _), N)",
    "aggregate_all(count, drm_edge(_, _, _, _), N)",
    "aggregate_all(count, reachable(c0, _, _, _), N)",
    "aggregate_all(count, committed_map(_), N)",
    "aggregate_all(count, loop_closure(_, _, _, _), N)",
    "aggregate_all(count, joinable(_, _), N)",
    "aggregate_all(count, eig_point(_, _, _), N)",
    "aggregate_all(count, mission_step(_, _, _), N)",
    "aggregate_all(count, reachable(rn0a, c1, _, _), N)",
    "aggregate_all(max(P), rec(_, _, P), N)",
]


def relation_names() -> set[str]:
    """query.pl's relation_goal/3 heads, Name/Arity, read from the rule file."""
    text = (ROOT / "prolog" / "query.pl").read_text()
    heads = re.findall(r"^relation_goal\([A-Z_]\w*, (\w+)\(([^)]*)\),", text, re.MULTILINE)
    return {f"{n}/{len(args.split(','))}" for n, args in heads}


def copy_repl(goals: list[str], data_dir: Path) -> str:
    env = {**os.environ, "CHIZU_DATA_DIR": str(data_dir)}
    text = "".join(f"{g}.\n" for g in goals) + "halt.\n"
    r = subprocess.run([sys.executable, "-m", "chizu.service.cli", "repl", "demo"],
                       input=text, capture_output=True, text=True, timeout=120, env=env,
                       cwd=ROOT)
    assert "world demo loaded" in r.stdout, r.stdout + r.stderr
    return r.stdout + r.stderr


def test_the_copy_repl_defines_every_allowed_relation(tmp_path: Path) -> None:
    names = relation_names()
    assert {"frec/3", "landmark/1", "committed_map/1", "loop_closure/4", "joinable/2",
            "state_after/2"} <= names
    out = copy_repl(["forall(repl:world_goal(P), (write(P), nl))",
                     "forall(repl:world_goal(N/A), (functor(H, N, A), "
                     "predicate_property(user:H, imported_from(repl)) -> true ; "
                     "writeln(missing(N/A))))"], tmp_path)
    listed = set(re.findall(r"^(\w+/\d+)$", out, re.MULTILINE))
    assert listed == names
    assert "missing(" not in out


def test_the_same_goals_answer_alike_at_every_door(client: TestClient,
                                                  tmp_path: Path) -> None:
    rest = []
    for goal in COUNTS:
        r = client.post("/worlds/demo/query", json={"goal": goal})
        assert r.status_code == 200, (goal, r.text)
        rest.append(r.json()["solutions"][0]["N"])
    out: list[str] = []
    lines = [f"{g}." for g in COUNTS] + ["state_after([], S).", "halt."]
    it = iter(lines)
    LiveRepl(client, "demo", out.append).run(lambda _prompt: next(it))
    live = [float(m) for m in re.findall(r"\bN = ([-\d.e]+)", "\n".join(out))]
    copy = copy_repl([f"{g}, format('N=~w~n', [N])" for g in COUNTS]
                     + ["state_after([], S), format('S=~w~n', [S])"], tmp_path)
    copied = [float(m) for m in re.findall(r"^N=(\S+)$", copy, re.MULTILINE)]
    assert [float(x) for x in rest] == live == copied, (rest, live, copied)
    assert sum(x > 0 for x in rest) >= 8  # the demo world's relations are there to count
    # the localization state's rule under one name everywhere (was eig_state_after/2)
    state = client.post("/worlds/demo/query", json={"goal": "state_after([], S)"})
    s = state.json()["solutions"][0]["S"]
    assert f"S = {s}" in out and f"\nS={s}\n" in copy, (s, out, copy)

"""``chizu repl --live``: a Prolog prompt whose goals run in the running service's own
knowledge base, through the sandboxed query endpoint (``POST /worlds/{world}/query``).

What a user sees here is what the planners see now, not a snapshot: the same engine,
the same facts, the same time and inference limits, read-only. It talks HTTP only (no
Prolog in this process), to localhost unless told otherwise.

At the prompt, as in swipl: a goal ends with a full stop (it may span lines); after
each answer ``;`` asks for the next one and Enter stops; ``halt.`` or ctrl-D leaves.
Ctrl-C during a query drops the connection, and the service stops the goal within
0.1 s (a goal whose client left is cancelled).
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Callable, Iterator
from typing import Any
from urllib.parse import urlsplit

import httpx

PAGE = 10  #: solutions fetched at first; each further page doubles it
MAX_SOLUTIONS = 10_000  #: the endpoint's own cap
LOOPBACK_NAMES = {"localhost"}


class ReplError(Exception):
    """The REPL cannot start (a remote URL without permission, an unknown world)."""


def check_local(url: str, allow_remote: bool) -> None:
    """Refuse a service that is not on this machine unless ``allow_remote``."""
    host = urlsplit(url).hostname or ""
    if allow_remote or host in LOOPBACK_NAMES:
        return
    try:
        if ipaddress.ip_address(host).is_loopback:
            return
    except ValueError:
        pass
    raise ReplError(f"{url} is not on this machine; pass --allow-remote to query it")


def format_value(v: Any) -> str:
    return v if isinstance(v, str) else json.dumps(v)


def format_solution(sol: dict[str, Any]) -> str:
    """``X = a, P = 0.9`` for the bindings, ``true`` when there are none."""
    if not sol:
        return "true"
    return ",\n".join(f"{k} = {format_value(v)}" for k, v in sol.items())


class LiveRepl:
    """A prompt on ``world`` of the service ``client`` talks to."""

    def __init__(self, client: httpx.Client, world: str,
                 write: Callable[[str], None] = print) -> None:
        self.client, self.world, self.write = client, world, write

    def check_world(self) -> None:
        r = self.client.get(f"/worlds/{self.world}")
        if r.status_code != 200:
            raise ReplError(_problem(r))

    def solutions(self, goal: str) -> Iterator[dict[str, Any]]:
        """The goal's solutions in order, fetched a page at a time (a further page runs
        the goal again with a larger ``max_solutions``: the engine keeps no open query
        between requests). Raises :class:`ReplError` with the service's problem."""
        shown, n = 0, PAGE
        while True:
            r = self.client.post(f"/worlds/{self.world}/query",
                                 json={"goal": goal, "max_solutions": n})
            if r.status_code != 200:
                raise ReplError(_problem(r))
            body = r.json()
            yield from body["solutions"][shown:]
            shown = len(body["solutions"])
            if not body["truncated"] or n >= MAX_SOLUTIONS:
                return
            n = min(2 * n, MAX_SOLUTIONS)

    def run(self, read: Callable[[str], str]) -> None:
        """The loop; ``read(prompt)`` gives a line (raises EOFError at the end)."""
        while True:
            try:
                goal = self._read_goal(read)
            except KeyboardInterrupt:
                self.write("")
                continue
            except EOFError:
                self.write("")
                return
            if goal in ("halt", "halt()"):
                return
            try:
                self._answer(goal, read)
            except KeyboardInterrupt:  # the connection is dropped: the goal is stopped
                self.write("% interrupted")
            except EOFError:
                return

    def _read_goal(self, read: Callable[[str], str]) -> str:
        lines: list[str] = []
        while True:
            line = read("?- " if not lines else "|    ").strip()
            if line:
                lines.append(line)
            text = " ".join(lines)
            if text.endswith("."):
                return text[:-1].strip()

    def _answer(self, goal: str, read: Callable[[str], str]) -> None:
        if not goal:
            return
        any_ = False
        try:
            for sol in self.solutions(goal):
                if any_:
                    if read(" ").strip() != ";":
                        self.write(".")
                        return
                any_ = True
                self.write(format_solution(sol))
        except ReplError as e:
            self.write(f"% {e}")
            return
        self.write("." if any_ else "false.")


def _problem(r: httpx.Response) -> str:
    try:
        p = r.json()
        field = f" ({p['field']})" if p.get("field") else ""
        return f"{p.get('title', r.status_code)}: {p.get('detail', '')}{field}"
    except (ValueError, KeyError, AttributeError):
        return f"HTTP {r.status_code}"

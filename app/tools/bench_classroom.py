"""`torquelab bench --classroom`: how many seats and watchers this machine carries.

For each seat count N (default 1, 2, 4, 8) it starts `torquelab classroom --seats N` (a process of
its own, as a teacher would), takes every seat with a headless websocket client that reads every
message as a page does, lets the seats run, then measures for `--seconds`: each seat's real-time
factor from its own status lines (simulated time over the seat's own clock: the whole window, the
median and the worst of its 1 s windows) and the messages (one per published frame) each client
receives per second. For each watcher count K (default 1, 10, 30) it does the same with one seat, its
student's client steering and K clients watching that seat read-only through the lobby (the
teacher's read-only view: the path the spotlight takes).
"""

from __future__ import annotations

import argparse
import contextlib
import http.client
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import viser
from websockets.sync.client import connect

from app.live.ui.viser_seam import camera_message

START_TIMEOUT_S = 180.0
WARM_SIM_S = 2.0  # every seat runs this much simulated time before the measurement


def windows_rtf(samples: list[tuple[float, float, bool]], window_s: float = 1.0) -> list[float]:
    """Real-time factors of consecutive windows of at least `window_s` of a seat's own clock, from its
    status samples (wall s, simulated s, running); a window in which the seat was paused is left out."""
    out: list[float] = []
    i = 0
    while i < len(samples):
        j = i + 1
        while j < len(samples) and samples[j][0] - samples[i][0] < window_s:
            j += 1
        if j >= len(samples):
            break
        if all(s[2] for s in samples[i : j + 1]):
            out.append((samples[j][1] - samples[i][1]) / (samples[j][0] - samples[i][0]))
        i = j
    return out


@dataclass
class Client:
    """A headless page: a websocket through the lobby that reads every message as it comes."""

    url: str
    cookie: str
    times: list[float] = field(default_factory=list)  # monotonic arrival time of each message
    closed: str = ""

    def start(self) -> None:

        self.ws = connect(
            self.url,
            subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
            additional_headers={"Cookie": self.cookie},
            open_timeout=30,
            max_size=None,
        )
        self.ws.send(camera_message())
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        try:
            for _ in self.ws:
                self.times.append(time.monotonic())
        except Exception as exc:
            self.closed = f"{type(exc).__name__}: {exc}"

    def rate(self, t0: float, t1: float) -> float:
        """Messages received per second between t0 and t1."""
        return sum(t0 <= t < t1 for t in self.times) / (t1 - t0)

    def close(self) -> None:
        self.ws.close()


class Classroom:
    """`torquelab classroom` as a child process: its links, its seats' rows from the teacher's socket."""

    def __init__(self, seats: int, scenario: str):
        command = [sys.executable, "-c", "import sys; from app.cli import main; sys.exit(main())", "classroom"]
        self.proc = subprocess.Popen(
            [*command, "--seats", str(seats), "--port", "0", "--scenario", scenario, "--idle", "3600"],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        lines = [self.proc.stdout.readline(), self.proc.stdout.readline()]
        base = re.search(r"(http://[\d.]+:\d+)/ ", lines[0])
        token = re.search(r"token=(\S+)", lines[1])
        if not base or not token:
            self.stop()
            raise RuntimeError(f"the classroom did not start: {''.join(lines).strip()}")
        self.base, self.token = base.group(1), token.group(1)
        host, port = self.base.removeprefix("http://").split(":")
        self.host: str = host
        self.port: str = port
        self.rows: list[dict[str, Any]] = []
        self.lobby_cores = float("nan")  # CPU the lobby used per wall second while measured
        self.samples: dict[int, list[tuple[float, float, bool]]] = {}
        self.cpu: dict[int, list[tuple[float, float]]] = {}  # seat → (its clock, its process's CPU seconds)
        self.teacher = connect(
            f"ws://{self.host}:{self.port}/teacher/ws",
            additional_headers={"Cookie": f"torquelab_teacher={self.token}"},
            open_timeout=30,
        )
        threading.Thread(target=self._feed, daemon=True).start()

    def _feed(self) -> None:
        try:
            for raw in self.teacher:
                msg = json.loads(raw)
                if "seats" not in msg:
                    continue
                self.rows = msg["seats"]
                for row in self.rows:
                    if row.get("wall") is not None and row.get("t") is not None:
                        samples = self.samples.setdefault(row["seat"], [])
                        if not samples or row["wall"] > samples[-1][0]:
                            samples.append((row["wall"], row["t"], bool(row["running"])))
                            if row.get("cpu_s") is not None:
                                self.cpu.setdefault(row["seat"], []).append((row["wall"], row["cpu_s"]))
        except Exception:
            pass

    def arrive(self) -> str:
        """A new student: the seat cookie the lobby gives."""
        conn = http.client.HTTPConnection(self.host, int(self.port), timeout=30)
        conn.request("GET", "/")
        resp = conn.getresponse()
        resp.read()
        cookie = resp.getheader("Set-Cookie") or ""
        conn.close()
        if resp.status != 302 or not cookie:
            raise RuntimeError(f"no seat given (HTTP {resp.status})")
        return cookie.split(";")[0]

    def lobby_cpu_s(self) -> float:
        """CPU seconds the lobby's process has used (Linux /proc; NaN elsewhere)."""
        try:
            with open(f"/proc/{self.proc.pid}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, IndexError, ValueError):
            return float("nan")

    def ws_url(self, path: str) -> str:
        return f"ws://{self.host}:{self.port}{path}"

    def stop(self) -> None:
        with contextlib.suppress(Exception):
            self.teacher.close()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def _wait_running(room: Classroom, seats: int, clients: list[Client]) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        rows = [r for r in room.rows if r["state"] == "ready"]
        if (
            len(rows) >= seats
            and all((r.get("t") or 0.0) >= WARM_SIM_S for r in rows)
            and all(len(c.times) > 10 for c in clients)
        ):
            return
        broken = [c.closed for c in clients if c.closed]
        if broken:
            raise RuntimeError(f"a client was closed: {broken[0]}")
        time.sleep(0.5)
    raise RuntimeError(f"the seats did not all run {WARM_SIM_S} s within {START_TIMEOUT_S:.0f} s")


def _cores(samples: list[tuple[float, float]], t0: float, t1: float) -> float:
    """CPU seconds per wall second between the samples nearest t0 and t1 (of the seat's clock)."""
    inside = [s for s in samples if t0 <= s[0] <= t1]
    if len(inside) < 2:
        return float("nan")
    return (inside[-1][1] - inside[0][1]) / (inside[-1][0] - inside[0][0])


def _measure(room: Classroom, clients: list[Client], seconds: float) -> tuple[list[dict[str, Any]], float, float]:
    start = {n: len(s) for n, s in room.samples.items()}
    t0 = time.monotonic()
    lobby0 = room.lobby_cpu_s()
    time.sleep(seconds)
    t1 = time.monotonic()
    room.lobby_cores = (room.lobby_cpu_s() - lobby0) / (t1 - t0)
    seats = []
    for number, samples in sorted(room.samples.items()):
        window = samples[max(0, start.get(number, 0) - 1) :]
        whole = (window[-1][1] - window[0][1]) / (window[-1][0] - window[0][0]) if len(window) > 1 else float("nan")
        ones = windows_rtf(window)
        seats.append(
            {
                "seat": number,
                "rtf": whole,
                "rtf_median_1s": statistics.median(ones) if ones else float("nan"),
                "rtf_worst_1s": min(ones) if ones else float("nan"),
                "windows": len(ones),
                "cores": _cores(room.cpu.get(number, []), t0, t1),
            }
        )
    return seats, t0, t1


def bench_seats(n: int, scenario: str, seconds: float) -> dict[str, Any]:
    """N seats, each taken by one reading client."""
    room = Classroom(n, scenario)
    clients: list[Client] = []
    try:
        for _ in range(n):
            client = Client(room.ws_url("/lab/view"), room.arrive())
            client.start()
            clients.append(client)
        _wait_running(room, n, clients)
        seats, t0, t1 = _measure(room, clients, seconds)
        rates = [c.rate(t0, t1) for c in clients]
        return {
            "seats": n,
            "per_seat": seats,
            "client_msgs_per_s": rates,
            "lobby_cores": room.lobby_cores,
            "load_average_1min": os.getloadavg()[0],
        }
    finally:
        for c in clients:
            with contextlib.suppress(Exception):
                c.close()
        room.stop()


def bench_watchers(k: int, scenario: str, seconds: float) -> dict[str, Any]:
    """One seat with its student's client and K clients watching it read-only through the lobby."""
    room = Classroom(1, scenario)
    clients: list[Client] = []
    try:
        student = Client(room.ws_url("/lab/view"), room.arrive())
        student.start()
        clients.append(student)
        _wait_running(room, 1, clients)
        for _ in range(k):
            watcher = Client(room.ws_url("/teacher/seat/1/view"), f"torquelab_teacher={room.token}")
            watcher.start()
            clients.append(watcher)
        _wait_running(room, 1, clients)
        seats, t0, t1 = _measure(room, clients, seconds)
        rates = [c.rate(t0, t1) for c in clients]
        return {
            "watchers": k,
            "seat": seats[0] if seats else {},
            "student_msgs_per_s": rates[0],
            "watcher_msgs_per_s": rates[1:],
            "lobby_cores": room.lobby_cores,
            "load_average_1min": os.getloadavg()[0],
        }
    finally:
        for c in clients:
            with contextlib.suppress(Exception):
                c.close()
        room.stop()


def _counts(text: str) -> list[int]:
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"expected counts like 1,2,4, got {text!r}") from None
    if not values or min(values) < 0:
        raise ValueError(f"expected counts like 1,2,4, got {text!r}")
    return values


def _fmt_rates(rates: list[float]) -> str:
    if not rates:
        return "-"
    return f"{min(rates):5.1f} / {statistics.median(rates):5.1f}"


def cmd_bench_classroom(args: argparse.Namespace) -> int:
    """Print the capacity tables (or JSON)."""
    seat_counts = _counts(args.seat_counts)
    watcher_counts = _counts(args.watcher_counts)
    report: dict[str, Any] = {
        "scenario": args.scenario,
        "seconds": args.seconds,
        "cpu_count": os.cpu_count(),
        "seats": [],
        "watch": [],
    }
    for n in seat_counts:
        if n < 1:
            continue
        print(f"torquelab: {n} seat(s) …", file=sys.stderr, flush=True)
        report["seats"].append(bench_seats(n, args.scenario, args.seconds))
    for k in watcher_counts:
        print(f"torquelab: 1 seat and {k} watcher(s) …", file=sys.stderr, flush=True)
        report["watch"].append(bench_watchers(k, args.scenario, args.seconds))
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(
        f"seats on this machine ({report['cpu_count']} cores), scenario {args.scenario}, {args.seconds:g} s each; "
        "RTF: simulated / wall time of each seat's own clock"
    )
    print(
        "| seats | RTF of each seat | median 1 s RTF (worst seat) | worst 1 s RTF | msgs/s per client (min / median) "
        "| cores per seat (mean) | lobby cores |"
    )
    print("|---|---|---|---|---|---|---|")
    for row in report["seats"]:
        per = row["per_seat"]
        rtfs = " ".join(f"{s['rtf']:.3f}" for s in per)
        medians = min((s["rtf_median_1s"] for s in per), default=float("nan"))
        worst = min((s["rtf_worst_1s"] for s in per), default=float("nan"))
        cores = statistics.fmean(s["cores"] for s in per) if per else float("nan")
        print(
            f"| {row['seats']} | {rtfs} | {medians:.3f} | {worst:.3f} | {_fmt_rates(row['client_msgs_per_s'])} "
            f"| {cores:.2f} | {row['lobby_cores']:.2f} |"
        )
    print()
    print("one seat watched read-only through the lobby (its student's client steering)")
    print(
        "| watchers | seat RTF | median 1 s RTF | worst 1 s RTF | student msgs/s | watcher msgs/s (min / median) "
        "| seat cores | lobby cores |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for row in report["watch"]:
        s = row["seat"]
        print(
            f"| {row['watchers']} | {s.get('rtf', float('nan')):.3f} | {s.get('rtf_median_1s', float('nan')):.3f} "
            f"| {s.get('rtf_worst_1s', float('nan')):.3f} | {row['student_msgs_per_s']:.1f} "
            f"| {_fmt_rates(row['watcher_msgs_per_s'])} | {s.get('cores', float('nan')):.2f} "
            f"| {row['lobby_cores']:.2f} |"
        )
    return 0

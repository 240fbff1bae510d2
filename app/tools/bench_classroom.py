"""`torquelab bench --classroom`: how many seats and watchers this machine carries.

For each seat count N (default 1, 2, 4, 8) it starts `torquelab classroom --seats N` (a process of
its own, as a teacher would), takes every seat with a headless websocket client that reads every
message as a page does, lets the seats run, then measures for `--seconds`: each seat's real-time
factor from its own status lines (simulated time over the seat's own clock: the whole window, the
median and the worst of its 1 s windows) and the messages (one per published frame) each client
receives per second. For each watcher count K (default 1, 10, 30) it does the same with one seat, its
student's client steering and K clients watching that seat read-only through the lobby (the
teacher's read-only view: the path the spotlight takes).

With `--chromium-pages` each seat's student is a real page instead: a headless Chromium (one browser,
a context of its own per student, as separate browsers have separate cookies) opens the class's link,
is given a seat and shows the lab; the page counts in itself the frames it receives (the batches
viser's websocket worker hands the page, one per published frame) and the frames it draws (animation
frames in which the 3D view made a WebGL call), and the browser's CPU (every Chromium process)
is measured beside the seats' and the lobby's. The watchers stay websocket clients.
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
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import viser
from websockets.sync.client import connect

from app.live.ui.viser_seam import camera_message

START_TIMEOUT_S = 240.0
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

    def ready(self) -> bool:
        return len(self.times) > 10

    def begin(self) -> None:
        """The measurement starts (the arrival times say the rest)."""

    def end(self) -> None:
        """The measurement ends."""

    def close(self) -> None:
        self.ws.close()


# Run in every frame of a page before its own scripts: counts the frames viser's websocket worker
# hands the page (one "message_batch" per message the server sent) and the animation frames in which
# a WebGL call was made (the 3D view drew; the plots draw on 2D canvases).
PAGE_COUNTERS_JS = """(() => {
  if (window.__torquelabCounts) return;
  const counts = window.__torquelabCounts = {received: 0, drawn: 0};
  const BaseWorker = window.Worker;
  window.Worker = class extends BaseWorker {
    constructor(...args) {
      super(...args);
      this.addEventListener("message", (e) => { if (e.data && e.data.type === "message_batch") counts.received += 1; });
    }
  };
  let frameTime = -1, counted = true, inFrame = false;
  for (const proto of [window.WebGL2RenderingContext, window.WebGLRenderingContext].map((c) => c && c.prototype)) {
    if (!proto) continue;
    for (const name of ["clear", "drawArrays", "drawElements"]) {
      const call = proto[name];
      proto[name] = function (...args) {
        if (inFrame && !counted) { counted = true; counts.drawn += 1; }
        return call.apply(this, args);
      };
    }
  }
  const raf = window.requestAnimationFrame.bind(window);
  window.requestAnimationFrame = (cb) => raf((t) => {
    if (t !== frameTime) { frameTime = t; counted = false; }
    inFrame = true;
    try { cb(t); } finally { inFrame = false; }
  });
})();"""
# the lab's counts and the page's clock (ms) when they were read: a loaded page answers late, so the rate
# is taken over the page's own time between two readings, not over the time the bench asked
LAB_COUNTS_JS = """() => { const f = document.getElementById('mine'), c = f && f.contentWindow.__torquelabCounts;
  return c && {received: c.received, drawn: c.drawn, at: performance.now()}; }"""


@dataclass
class PageClient:
    """A student's page in headless Chromium: the class's link opened in a browser context of its own
    (its own cookie: its own seat); the lab's counters (`PAGE_COUNTERS_JS`) read at the measurement's
    start and end."""

    browser: Any
    url: str
    closed: str = ""
    marks: list[tuple[float, dict[str, float]]] = field(default_factory=list)  # (monotonic time, counts and page clock)

    def start(self) -> None:
        self.context = self.browser.new_context(viewport={"width": 1280, "height": 800})
        self.context.add_init_script(PAGE_COUNTERS_JS)
        self.page = self.context.new_page()
        self.page.goto(self.url, wait_until="commit")

    def counts(self) -> dict[str, float] | None:
        try:
            return self.page.evaluate(LAB_COUNTS_JS)
        except Exception as exc:  # a page that went away: said, not fatal here
            self.closed = f"{type(exc).__name__}: {exc}"
            return None

    def ready(self) -> bool:
        counts = self.counts()
        return bool(counts and counts["received"] > 10 and counts["drawn"] > 0)

    def begin(self) -> None:
        self.marks = [(time.monotonic(), self.counts() or {})]

    def end(self) -> None:
        self.marks.append((time.monotonic(), self.counts() or {}))

    def _per_s(self, key: str) -> float:
        if len(self.marks) < 2 or key not in self.marks[0][1] or key not in self.marks[1][1]:
            return float("nan")
        c0, c1 = self.marks[0][1], self.marks[1][1]
        return (c1[key] - c0[key]) / ((c1["at"] - c0["at"]) / 1000.0)  # over the page's own clock

    def rate(self, t0: float, t1: float) -> float:
        """Frames received per second over the measurement (between this page's own marks)."""
        return self._per_s("received")

    def drawn_rate(self) -> float:
        """Frames drawn per second over the measurement."""
        return self._per_s("drawn")

    def wait(self, seconds: float) -> None:
        """Let `seconds` pass while Playwright reads what the browser sends (a driver left unread stalls
        the browser: its pages then receive and draw nothing)."""
        self.page.wait_for_timeout(seconds * 1000.0)

    def close(self) -> None:
        self.context.close()


def chromium_cpu_s() -> float:
    """CPU seconds used so far by the Chromium processes descended from this one (Linux /proc; NaN elsewhere)."""
    try:
        parent: dict[int, int] = {}
        cpu: dict[int, float] = {}
        names: dict[int, str] = {}
        tick = os.sysconf("SC_CLK_TCK")
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    head, tail = fh.read().rsplit(")", 1)
            except OSError:
                continue
            fields = tail.split()
            pid = int(entry)
            parent[pid], names[pid] = int(fields[1]), head.split("(", 1)[1]
            cpu[pid] = (int(fields[11]) + int(fields[12])) / tick
    except (OSError, ValueError, IndexError):
        return float("nan")
    me = os.getpid()

    def descends(pid: int) -> bool:
        while pid > 1:
            pid = parent.get(pid, 0)
            if pid == me:
                return True
        return False

    return sum(c for pid, c in cpu.items() if names[pid].startswith(("chrom", "headless")) and descends(pid))


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
        self.browser_cores = float("nan")  # CPU the Chromium pages used per wall second while measured
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


@contextlib.contextmanager
def chromium_browser() -> Iterator[Any]:
    """A headless Chromium driven by Playwright (the test extra), at $TORQUELAB_CHROMIUM or /usr/bin/chromium."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        raise ValueError("--chromium-pages needs Playwright: pip install 'torquelab[test]'") from None
    from app.tools.bench_serve import CHROMIUM, CHROMIUM_ARGS

    if not os.path.exists(CHROMIUM):
        raise ValueError(f"no Chromium at {CHROMIUM}; set TORQUELAB_CHROMIUM to a Chromium binary")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


def _wait_running(room: Classroom, seats: int, clients: list[Any]) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        rows = [r for r in room.rows if r["state"] == "ready"]
        if (
            len(rows) >= seats
            and all((r.get("t") or 0.0) >= WARM_SIM_S for r in rows)
            and all(c.ready() for c in clients)
        ):
            return
        broken = [c.closed for c in clients if c.closed]
        if broken:
            raise RuntimeError(f"a client was closed: {broken[0]}")
        next((c.wait for c in clients if isinstance(c, PageClient)), time.sleep)(0.5)
    raise RuntimeError(f"the seats did not all run {WARM_SIM_S} s within {START_TIMEOUT_S:.0f} s")


def _cores(samples: list[tuple[float, float]], t0: float, t1: float) -> float:
    """CPU seconds per wall second between the samples nearest t0 and t1 (of the seat's clock)."""
    inside = [s for s in samples if t0 <= s[0] <= t1]
    if len(inside) < 2:
        return float("nan")
    return (inside[-1][1] - inside[0][1]) / (inside[-1][0] - inside[0][0])


def _measure(room: Classroom, clients: list[Any], seconds: float) -> tuple[list[dict[str, Any]], float, float]:
    for c in clients:
        c.begin()
    start = {n: len(s) for n, s in room.samples.items()}
    t0 = time.monotonic()
    lobby0, browser0 = room.lobby_cpu_s(), chromium_cpu_s()
    pump = next((c.wait for c in clients if isinstance(c, PageClient)), time.sleep)
    pump(seconds)
    t1 = time.monotonic()
    room.lobby_cores = (room.lobby_cpu_s() - lobby0) / (t1 - t0)
    room.browser_cores = (chromium_cpu_s() - browser0) / (t1 - t0)
    for c in clients:
        c.end()
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


def bench_seats(n: int, scenario: str, seconds: float, browser: Any = None) -> dict[str, Any]:
    """N seats, each taken by one reading client, or, given a Playwright `browser`, by one Chromium page."""
    room = Classroom(n, scenario)
    clients: list[Any] = []
    try:
        for _ in range(n):
            client: Any = (
                Client(room.ws_url("/lab/view"), room.arrive())
                if browser is None
                else PageClient(browser, room.base + "/")
            )
            client.start()
            clients.append(client)
        _wait_running(room, n, clients)
        load0 = os.getloadavg()[0]
        seats, t0, t1 = _measure(room, clients, seconds)
        rates = [c.rate(t0, t1) for c in clients]
        out = {
            "seats": n,
            "per_seat": seats,
            "client_msgs_per_s": rates,
            "lobby_cores": room.lobby_cores,
            "load_average_1min": os.getloadavg()[0],
            "load_average_1min_start": load0,
        }
        if browser is not None:
            out["pages_drawn_per_s"] = [c.drawn_rate() for c in clients]
            out["browser_cores"] = room.browser_cores
        return out
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
    """Counts like "1,2,4"; "none" (or "") is none."""
    if text.strip().lower() in ("", "none"):
        return []
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"expected counts like 1,2,4, got {text!r}") from None
    if min(values, default=-1) < 0:
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
    pages = bool(getattr(args, "chromium_pages", False))
    report["students"] = "chromium pages" if pages else "websocket clients"
    with chromium_browser() if pages else contextlib.nullcontext() as browser:
        for n in seat_counts:
            if n < 1:
                continue
            print(f"torquelab: {n} seat(s) …", file=sys.stderr, flush=True)
            report["seats"].append(bench_seats(n, args.scenario, args.seconds, browser))
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
    if pages:
        print(
            "each seat's student a headless Chromium page; frames received: viser's batches handed to the page; "
            "frames drawn: animation frames in which its 3D view drew"
        )
        print(
            "| seats | RTF of each seat | median 1 s RTF (worst seat) | worst 1 s RTF "
            "| frames received/s per page (min / median) | frames drawn/s per page (min / median) "
            "| cores per seat (mean) | lobby cores | browser cores |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
    else:
        print(
            "| seats | RTF of each seat | median 1 s RTF (worst seat) | worst 1 s RTF "
            "| msgs/s per client (min / median) | cores per seat (mean) | lobby cores |"
        )
        print("|---|---|---|---|---|---|---|")
    for row in report["seats"]:
        per = row["per_seat"]
        rtfs = " ".join(f"{s['rtf']:.3f}" for s in per)
        medians = min((s["rtf_median_1s"] for s in per), default=float("nan"))
        worst = min((s["rtf_worst_1s"] for s in per), default=float("nan"))
        cores = statistics.fmean(s["cores"] for s in per) if per else float("nan")
        line = f"| {row['seats']} | {rtfs} | {medians:.3f} | {worst:.3f} | {_fmt_rates(row['client_msgs_per_s'])} "
        if pages:
            line += f"| {_fmt_rates(row['pages_drawn_per_s'])} "
        line += f"| {cores:.2f} | {row['lobby_cores']:.2f} |"
        print(line + (f" {row['browser_cores']:.2f} |" if pages else ""))
    loads = [f"{r['load_average_1min_start']:.1f}→{r['load_average_1min']:.1f}" for r in report["seats"]]
    if loads:
        print(f"load average (1 min) at each row's start→end: {', '.join(loads)}")
    if not report["watch"]:
        return 0
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

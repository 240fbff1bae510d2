"""Typed numbers parsed on the server (`app.live.ui.typed`): what a number box's text means, and the
route from the page's channel to an input (the page's script itself: tests/test_browser.py)."""

from __future__ import annotations

import base64
import json
import re
from types import SimpleNamespace

import pytest

from app.live.ui.typed import TYPED_JS, TypedNumbers, page_html, parse_typed
from app.live.ui.viser_seam import input_uuid


@pytest.mark.parametrize(
    ("text", "value", "why"),
    [
        ("12.5", 12.5, ""),
        (" 1e2 ", 100.0, ""),
        ("1e9", 1000.0, "is above the largest value 1000"),
        ("\u22123", 1.0, "is below the smallest value 1"),  # a typographic minus
        ("2,5", 2.5, ""),  # a decimal comma
        ("abc", None, "is not a number"),
        ("", None, "is empty"),
        ("NaN", None, "is not a finite number"),
        ("inf", None, "is not a finite number"),
        ("1,000.5", None, "is not a number"),
    ],
)
def test_parse_typed_gives_the_number_the_clamp_or_why_not(text, value, why):
    assert parse_typed(text, 1.0, 1000.0) == (value, why)


def test_parse_typed_without_bounds_takes_any_finite_number():
    assert parse_typed("-1e300", None, None) == (-1e300, "")


def test_the_page_html_runs_the_script_once_from_an_images_error_handler():
    html = page_html("typed number")
    encoded = re.search(r"atob\('([A-Za-z0-9+/=]+)'\)", html)
    assert encoded is not None and 'src="data:,"' in html and "onerror=" in html
    code = base64.b64decode(encoded.group(1)).decode("utf-8")
    assert code == TYPED_JS.replace("%CHANNEL%", json.dumps("typed number"))
    assert "window.__torquelabTyped" in code and '"' not in html.split('onerror="', 1)[1].rstrip('">')


def _event(value: str, client_id: int | None = 7) -> SimpleNamespace:
    return SimpleNamespace(client_id=client_id, target=SimpleNamespace(value=value))


def test_the_channel_sends_a_registered_inputs_text_to_its_handler(server):
    typed = TypedNumbers(server)
    box = server.gui.add_number("Seconds", 10.0, min=0.1, max=60.0)
    got: list[tuple[str, int | None]] = []
    typed.register(box, lambda text, cid: got.append((text, cid)))
    typed._on_channel(_event(json.dumps({"id": input_uuid(box), "text": "1e9", "n": 1})))
    typed._on_channel(_event("not json"))  # not what the page sends: ignored
    typed._on_channel(_event(json.dumps({"id": input_uuid(box), "text": "x"}), client_id=None))  # our own write
    assert got == [("1e9", 7)] and typed.received == 1


def test_an_unregistered_number_box_is_clamped_to_its_range_or_kept(server):
    typed = TypedNumbers(server)
    box = server.gui.add_number("Seconds", 10.0, min=0.1, max=60.0)
    typed._on_channel(_event(json.dumps({"id": input_uuid(box), "text": "1e9"})))
    assert box.value == pytest.approx(60.0)
    typed._on_channel(_event(json.dumps({"id": input_uuid(box), "text": "NaN"})))
    assert box.value == pytest.approx(60.0)
    typed._on_channel(_event(json.dumps({"id": input_uuid(box), "text": "2.5"})))
    assert box.value == pytest.approx(2.5)

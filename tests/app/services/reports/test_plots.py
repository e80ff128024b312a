"""The report's plot renderer: real PNGs from plotly through kaleido, and a 503 naming what is
missing where the renderer is not installed."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

from app.services.reports import plots
from app.services.reports.content import LimitLine, Panel, Series

ROOT = Path(__file__).resolve().parents[4]


def test_a_panel_renders_to_a_png_of_the_report_size() -> None:
    panel = Panel("egt_margin", "EGT margin", "EGT margin",
                  (Series("egt_margin", "degC", [40.0, 38.5, None, 36.0], [1.0, 1.0, None, 1.2]),),
                  (LimitLine("egt_margin", "amber", 25.0), LimitLine("egt_margin", "red", 0.0)))
    time = ["2026-01-01T00:00:00Z", "2026-01-02T00:00:00Z", "2026-01-03T00:00:00Z",
            "2026-01-04T00:00:00Z"]
    figure = plots.panel_figure(panel, time)
    # The band (upper, lower) and the line; the limits as lines with their level.
    assert [t.name for t in figure.data] == [None, None, "egt_margin"]
    assert list(figure.data[0].y) == [41.0, 39.5, None, 37.2]
    assert [s.y0 for s in figure.layout.shapes] == [25.0, 0.0]
    [image] = plots.engine_images((panel,), time)
    assert image.png.startswith(b"\x89PNG\r\n\x1a\n")
    width, height = struct.unpack(">II", image.png[16:24])  # the IHDR chunk
    assert (width, height) == (plots.WIDTH * plots.SCALE, plots.HEIGHT * plots.SCALE)


def test_a_missing_renderer_is_a_503_naming_it() -> None:
    # A process where kaleido cannot be imported, as on an install without it.
    code = (
        "import sys; sys.modules['kaleido'] = None\n"
        "import plotly.graph_objects as go\n"
        "from app.errors import ServiceUnavailable\n"
        "from app.services.reports import plots\n"
        "try:\n"
        "    plots.png(go.Figure())\n"
        "except ServiceUnavailable as exc:\n"
        "    print(exc.status_code, exc.message)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("503 report plots cannot be rendered")
    assert "kaleido" in result.stdout

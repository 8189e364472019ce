"""``solarnav replay --float32``: the states and diagnostics in float32 except the log clock and the geodetic
angles, equal to the float64 run rounded to float32, in a smaller file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from app.cli import main
from workflows.replay import FLOAT64_COLUMNS

SAMPLE = Path(__file__).resolve().parents[1] / "sample_logs" / "failed_cell.ulg"


def test_float32_narrows_every_float_column_but_time_and_latitude_longitude(tmp_path):
    written = {}
    for flag in ([], ["--float32"]):
        states, diagnostics = tmp_path / f"states{len(flag)}.parquet", tmp_path / f"diag{len(flag)}.parquet"
        assert main(["replay", str(SAMPLE), "--estimators", "three_stage,full_state_direct", *flag, "-o",
                     str(states), "--diagnostics", str(diagnostics)]) == 0
        written[bool(flag)] = (states, diagnostics)
    for wide_path, narrow_path in zip(written[False], written[True], strict=True):
        wide, narrow = pd.read_parquet(wide_path), pd.read_parquet(narrow_path)
        assert list(narrow.columns) == list(wide.columns) and len(narrow) == len(wide)
        for name, dtype in wide.dtypes.items():
            if dtype == np.float64:
                expected = np.float64 if name in FLOAT64_COLUMNS else np.float32
                assert narrow[name].dtype == expected, name
                np.testing.assert_array_equal(narrow[name].to_numpy(), wide[name].to_numpy().astype(expected))
            else:
                assert narrow[name].dtype == dtype, name
                assert narrow[name].equals(wide[name]), name
        assert narrow_path.stat().st_size < 0.8 * wide_path.stat().st_size
    assert {"time_s", "lat_deg", "lon_deg"} <= set(pd.read_parquet(written[True][0]).columns)

"""Fixtures of the rerun tests: a private rerun config with analytics off, and an .rrd reader.

The reader uses rerun's own API (rerun.chunk.RrdReader) and returns plain Python values,
so tests compare what was written with what comes back from the file.
"""
from __future__ import annotations

import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

RERUN_CLI = Path(sys.prefix) / 'bin' / 'rerun'


@pytest.fixture(scope='session', autouse=True)
def rerun_config(tmp_path_factory):
    """Keep rerun's config and data out of ~ (also for child processes) and analytics off."""
    base = tmp_path_factory.mktemp('rerun_home')
    saved = {k: os.environ.get(k) for k in ('XDG_CONFIG_HOME', 'XDG_DATA_HOME')}
    os.environ['XDG_CONFIG_HOME'] = str(base / 'config')
    os.environ['XDG_DATA_HOME'] = str(base / 'data')
    # 0.41 has no environment switch for analytics; its config file is the switch.
    subprocess.run([str(RERUN_CLI), 'analytics', 'disable'], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=60)
    yield base
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


class Recording:
    """Rows of an .rrd file by entity path (without the leading '/').

    ``rows[path]`` is a list of dicts, one per logged row, sorted by the temporal index,
    with timeline values as int (ns for timestamps) and components by their column name
    (e.g. ``'LineStrips3D:strips'``) as Python lists. ``static`` holds static rows.
    """

    def __init__(self, path: Path):
        import pyarrow as pa
        from rerun.chunk import RrdReader

        self.path = path
        reader = RrdReader(str(path))
        self.blueprints = reader.blueprints()
        self.recordings = reader.recordings()
        # store() needs the footer/manifest a closed file sink writes: this is how the
        # tests check that a recording was closed properly.
        self.store = reader.store()
        self.rows: dict[str, list[dict]] = defaultdict(list)
        self.static: dict[str, dict] = {}
        for chunk in reader.stream().to_chunks():
            entity = chunk.entity_path.lstrip('/')
            batch = chunk.to_record_batch()
            columns = {}
            for name, column in zip(batch.schema.names, batch.columns):
                if name == 'rerun.controls.RowId':
                    continue
                if pa.types.is_timestamp(column.type) or pa.types.is_duration(column.type):
                    column = column.cast(pa.int64())
                columns[name] = column.to_pylist()
            for i in range(batch.num_rows):
                row = {name: values[i] for name, values in columns.items()}
                if chunk.is_static:
                    self.static.setdefault(entity, {}).update(
                        {k: v for k, v in row.items() if v is not None})
                else:
                    self.rows[entity].append(row)
        for rows in self.rows.values():
            rows.sort(key=lambda r: (r.get('ros_time') or r.get('step') or 0,
                                     r.get('log_time') or 0))

    @property
    def entities(self) -> set[str]:
        return set(self.rows) | set(self.static)

    def values(self, entity: str, component: str) -> list:
        """The non-null values of one component of one entity, in time order."""
        return [r[component] for r in self.rows.get(entity, []) if r.get(component) is not None]

    def scalars(self, entity: str) -> list[float]:
        return [v[0] for v in self.values(entity, 'Scalars:scalars')]

    def times(self, entity: str, timeline: str = 'ros_time') -> list[int]:
        return [r[timeline] for r in self.rows.get(entity, [])]


@pytest.fixture
def read_rrd():
    """read_rrd(path) -> Recording."""
    return Recording

"""Times the README's DuckDB query over a catalogue (benches/catalogue.rs
writes the files and runs this).

Usage: catalogue_query.py DIR QUERY_FILE

DIR holds `catalogue/` (one Parquet file per run) and `catalogue.parquet`
(the same runs compacted). The query reads `recordings/catalogue/*.parquet`;
it is pointed at each in turn. Each timing opens a fresh DuckDB connection,
runs the query and fetches every row (the Python process and the `duckdb`
import are not counted); then whole `python -c` processes (interpreter,
import, query) over the compacted file.
"""

import statistics
import subprocess
import sys
import time

import duckdb

directory, query_file = sys.argv[1], sys.argv[2]
query = open(query_file).read()
PLACE = "recordings/catalogue/*.parquet"
assert PLACE in query, query


def timed(source, reps):
    q = query.replace(PLACE, source)
    times, rows = [], None
    for _ in range(reps):
        t0 = time.perf_counter()
        con = duckdb.connect()
        rows = con.sql(q).fetchall()
        con.close()
        times.append(time.perf_counter() - t0)
    return rows, times


def report(name, rows, times):
    print(
        f"{name}: {len(rows)} rows; first {times[0] * 1e3:.1f} ms, "
        f"median {statistics.median(times) * 1e3:.1f} ms, "
        f"min {min(times) * 1e3:.1f} ms, max {max(times) * 1e3:.1f} ms "
        f"over {len(times)} queries"
    )


compacted = f"{directory}/catalogue.parquet"
rows_c, t_c = timed(compacted, 30)
report("compacted catalogue.parquet", rows_c, t_c)
rows_f, t_f = timed(f"{directory}/catalogue/*.parquet", 5)
report("folder of per-run files", rows_f, t_f)
assert sorted(rows_c) == sorted(rows_f), "the two catalogues disagree"

q = query.replace(PLACE, compacted)
script = f"import duckdb; duckdb.sql({q!r}).fetchall()"
walls = []
for _ in range(5):
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", script], check=True)
    walls.append(time.perf_counter() - t0)
print(
    f"whole process (python -c: interpreter, import duckdb {duckdb.__version__}, query) "
    f"over the compacted file: median {statistics.median(walls) * 1e3:.0f} ms, "
    f"min {min(walls) * 1e3:.0f} ms, max {max(walls) * 1e3:.0f} ms"
)

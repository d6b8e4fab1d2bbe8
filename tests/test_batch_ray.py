"""``vispeech batch --backend ray``: on a local Ray instance, the same files as the process pool."""

import json
import threading

from conftest import require_module
from test_batch import RECORD, SAY_FILES, _assert_same_files, _jsonl
from vispeech.batch import run_batch

ray = require_module("ray", "Ray (the ray extra: pip install 'vispeech[ray]')")

ENGLISH = ["The captain found a blue boat.", "My mom made a large map.", "Five paper lamps before dawn.",
           "Bin blue at F two now.", "Every pilot opened the box."]
SWEDISH = ["Kaptenen hittade en blå båt.", "Mamma plockar blåbär.", "Fem papperslampor före gryningen.",
           "Varje pilot öppnade lådan.", "Hej! Hur kan jag hjälpa dig?"]


def test_ray_writes_what_the_process_pool_writes(tmp_path):
    records = []
    for i in range(200):
        lang, texts = ("en", ENGLISH) if i % 2 == 0 else ("sv", SWEDISH)
        records.append({"id": f"l{i:03d}", "text": f"{texts[i // 2 % 5][:-1]} {i}.", "language": lang})
    records[7] = {"id": "l007", "audio": "job.jsonl"}  # fails on a worker: not audio
    job = _jsonl(tmp_path / "job.jsonl", records)
    local = run_batch(job, tmp_path / "local", workers=2)
    clustered = run_batch(job, tmp_path / "ray", workers=2, backend="ray")
    assert [(r.id, r.status, r.key, r.files) for r in clustered.results] == \
        [(r.id, r.status, r.key, r.files) for r in local.results]
    assert clustered.count("written") == 199
    failure = clustered.results[7]
    assert failure.status == "failed" and failure.error == local.results[7].error
    assert "Traceback" not in failure.error and "Ray" not in failure.error
    for result in clustered.results:
        if result.status == "written":
            _assert_same_files(tmp_path / "ray" / result.id, tmp_path / "local" / result.id, SAY_FILES | {RECORD})
    index = [json.loads(line) for line in (tmp_path / "ray" / "index.jsonl").read_text().splitlines()]
    assert [row["status"] for row in index] == [r.status for r in clustered.results]

    again = run_batch(job, tmp_path / "ray", workers=2, backend="ray")  # resumable on Ray too
    assert again.count("unchanged") == 199


def test_ray_starts_no_more_actors_than_the_cluster_has_cpus(tmp_path):
    """On a running cluster with fewer CPUs than workers asked for, every line is written: an actor
    waiting for a CPU that never frees would hold the lines given to it forever."""
    job = _jsonl(tmp_path / "job.jsonl", [{"id": f"l{i}", "text": ENGLISH[i % 5]} for i in range(6)])
    reports = []
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        run = threading.Thread(target=lambda: reports.append(run_batch(job, tmp_path / "out", workers=3, backend="ray")))
        run.daemon = True
        run.start()
        run.join(90)
    finally:
        ray.shutdown()
    assert reports, "the batch did not end within 90 s"
    assert reports[0].count("written") == 6

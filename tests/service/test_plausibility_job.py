"""A reconstruct job carries the plausibility warnings: in its summary and its message."""

from __future__ import annotations


def test_service_reconstruct_job_carries_the_warnings(tube_xyz, tmp_path, store):
    from treesim.service.api.jobs import status_info
    from treesim.service.jobs.worker import done_message
    from treesim.service.processes import PROCESSES

    proc = PROCESSES["reconstruct"]
    summary = proc.execute(
        {"cloud": tube_xyz}, proc.parse({}), tmp_path, 1, lambda f, m: None, "tube"
    )
    codes = [w["code"] for w in summary["warnings"]]
    assert "form_factor_high" in codes
    message = done_message(summary)
    plural = "s" if len(codes) > 1 else ""
    assert message.startswith(f"done, {len(codes)} warning{plural}: stem form factor")
    job = store.create_job(
        process="reconstruct",
        inputs={},
        parameters={},
        max_attempts=1,
        time_limit_s=60.0,
        links=[],
    )
    claim = store.claim("w1", 60.0)
    assert claim is not None and claim.id == job["id"]
    assert store.succeed(claim, results=[], summary=summary, message=message)
    info = status_info(store.job(job["id"]))
    assert info.message == message
    assert [w["code"] for w in info.summary["warnings"]] == codes
    assert done_message({"warnings": []}) == "done"

"""haa_sym.check.verify: every row of the paper's equations passes for the bundled actuator."""


def test_verify_all_rows_pass(params):
    from haa_sym.check import verify
    rows = verify.run(params)
    failed = [r for r in rows if not r.ok]
    assert not failed, [(r.claim, r.numbers) for r in failed]
    assert len(rows) >= 14

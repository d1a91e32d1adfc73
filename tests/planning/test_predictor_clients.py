"""A one-process Predictor's Bullet clients: reused from draw to draw, and closed with it."""
from __future__ import annotations

from tests.planning.sim_scenes import column


def test_a_predictor_in_one_process_reuses_its_clients_and_predicts_the_same(monkeypatch):
    """Without a caller's ClientPool a one-process Predictor keeps one of its own (a rejected draw's
    client serves the next draw; a connect costs 10-70 ms): no world connects a client of its own,
    the predictions are those of a Predictor on a caller's pool, and closing it disconnects them."""
    from shelfpick.planning import sim as sim_module
    from shelfpick.planning.bullet_clients import ClientPool
    from shelfpick.planning.predict import Predictor

    scene = column(4).hide_depths()
    with ClientPool() as clients, Predictor(scene, samples=3, seed=2, clients=clients) as given:
        expected = [given.trial(frozenset(), b) for b in scene.ids]

    def refuse(gui: bool = False):
        raise AssertionError("a sample world connected a Bullet client of its own")

    monkeypatch.setattr(sim_module, "connect", refuse)
    pred = Predictor(scene, samples=3, seed=2)
    pool = pred._own_clients
    try:
        assert [pred.trial(frozenset(), b) for b in scene.ids] == expected
    finally:
        pred.close()
    assert pool is not None and pool._all == [] and pred._own_clients is None

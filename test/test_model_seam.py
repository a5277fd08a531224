"""
The actuator's model seam: a model with time in it runs on the rig unchanged, and maps are shared.

``LaggingModel`` is a small physics of its own, not a stand-in: the fluid reaches the segments
``lag_s`` after the pump pushed it (a pure transport delay in the line), and the segments then
sit at their quasi-static equilibrium. Its state changes between commands, so the batch runner
must advance it at its rate and record what it says at those instants.
"""

from collections import deque

import numpy as np

import softseq_ros
from softseq_ros.bag.reader import read_bag
from softseq_ros.quasistatic.solve import equilibrium_map
from softseq_ros.rig.model import QuasiStaticModel, actuator_model
from softseq_ros.scene.loader import load_scene
from softseq_ros.scene.programme import Leg

NS = 1_000_000_000


class LaggingModel:
    """The quasi-static equilibrium of the volume the pump had injected ``lag_s`` ago."""

    def __init__(self, inner: QuasiStaticModel, lag_s: float, rate_hz: float) -> None:
        self.inner = inner
        self.segments = inner.segments
        self.rest_volume_m3 = inner.rest_volume_m3
        self.rate_hz = rate_hz
        self.channel_names = inner.channel_names
        self.lag_ns = round(lag_s * NS)
        self._pending: deque[tuple[int, float]] = deque()

    def command(self, injected_m3, now_ns):
        # Nothing reaches the segments at once: the state changes only as time passes.
        self._pending.append((now_ns, injected_m3))
        return None

    def advance(self, now_ns):
        arrived = None
        while self._pending and self._pending[0][0] + self.lag_ns <= now_ns:
            _, arrived = self._pending.popleft()
        if arrived is None:
            return None
        return self.inner.command(arrived, now_ns) or []

    def state(self):
        return self.inner.state()

    def saved(self):
        return self.inner.saved()

    def resume(self, injected_m3, volumes_m3):
        self.inner.resume(injected_m3, volumes_m3)

    @property
    def end_stop_m3(self):
        return self.inner.end_stop_m3

    def check_programme(self, scene, profile):
        self.inner.check_programme(scene, profile)

    def channel_state(self):
        return self.inner.channel_state()

    def take_warnings(self):
        return self.inner.take_warnings()

    def take_notes(self):
        return self.inner.take_notes()


def test_a_model_with_time_is_advanced_at_its_rate_and_recorded(tmp_path):
    scene = load_scene('fig1_asymmetric')
    lag_s, rate_hz = 2.0, 7.0   # 7 Hz: its ticks fall between the pump's 50 Hz commands
    model = LaggingModel(QuasiStaticModel(equilibrium_map(scene.segments), scene.segment_names),
                         lag_s, rate_hz)
    result = softseq_ros.run(scene, tmp_path / 'bag', start_time_ns=0, model=model,
                             overrides={'pump': {'open_loop': True,
                                                 'legs': (Leg.inflate(6.0e-6),)}})
    assert result.pump_state == 'finished'
    commands = [(m.log_time_ns, m.msg.position[0])
                for m in read_bag(tmp_path / 'bag', ['/pump/command'])]
    volumes = [(m.log_time_ns, m.msg.header.stamp.sec * NS + m.msg.header.stamp.nanosec,
                sum(m.msg.position)) for m in read_bag(tmp_path / 'bag', ['/actuator/volumes'])]
    # Between two pump commands (50 Hz) the model was advanced at its own 7 Hz, and what it
    # said then went out stamped with the tick's time.
    pump_times = {t for t, _ in commands}
    ticks = [stamp for _, stamp, _ in volumes if stamp not in pump_times]
    assert ticks and all(stamp % round(NS / rate_hz) == 0 for stamp in ticks)
    # What the segments hold is what the pump had pushed lag_s before (the rest volume apart).
    times = np.array([t for t, _ in commands], dtype=float)
    pushed = np.array([v for _, v in commands])
    held = np.array([v for _, _, v in volumes]) - scene.segments[0].rest_volume \
        - scene.segments[1].rest_volume
    stamps = np.array([s for _, s, _ in volumes], dtype=float)
    at_ticks = np.isin(stamps, ticks) & (stamps > 5 * NS) & (stamps < 100 * NS)
    assert at_ticks.sum() > 100
    expected = np.interp(stamps[at_ticks] - lag_s * NS, times, pushed)
    np.testing.assert_allclose(held[at_ticks], expected,
                               atol=2 * scene.pump.profile.flow_rate / scene.pump.rate_hz)
    # A quasi-static actuator would already hold what was pushed at the tick itself.
    now = np.interp(stamps[at_ticks], times, pushed)
    assert np.all(now - held[at_ticks] > 0.9 * lag_s * scene.pump.profile.flow_rate)


def test_a_process_assembles_the_map_of_the_same_segments_once():
    scene = load_scene('paper')
    first, second = actuator_model(scene), actuator_model(scene)
    assert first is not second and first.emap is second.emap
    # The pump's reach and the actuator come from one map in one process.
    assert equilibrium_map(scene.segments) is first.emap
    assert equilibrium_map(scene.segments, 400) is not first.emap

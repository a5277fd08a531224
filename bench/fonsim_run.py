"""
Runs FONSim on a network that bench_dynamic.py describes; run by FONSim's own interpreter.

    <fonsim venv>/bin/python bench/fonsim_run.py JOB.json

JOB.json names the segments' p(V) CSV files (volume from the rest volume, gauge pressure, SI),
the channel, the fluid, the pump's volume flow, the duration and the fixed steps to run. For
each step this writes the times and the segments' volumes (from rest) into JOB's ``out`` (.npz)
and the wall time of ``Simulation.run`` alone (not the import, not the set-up) into ``out``'s
JSON twin. Nothing here imports softseq_ros: FONSim lives in its own environment.
"""

import contextlib
import importlib.metadata
import io
import json
from pathlib import Path
import sys
import time

import numpy as np


def network(fonsim, fluid, job):
    """Syringe (a volume-flow source) -> base segment -> channel -> ... -> tip segment."""
    system = fonsim.System()
    source = fonsim.VolumeflowSource('syringe', fluid=fluid, volumeflow=job['flow_m3_per_s'])
    segments = [fonsim.FreeActuator(f'segment{i}', fluid=fluid, curve=path, initial_volume=0.0)
                for i, path in enumerate(job['curves'])]
    channels = [fonsim.CircularTube(f'channel{j}', fluid=fluid, length=job['channel_length_m'],
                                    diameter=2.0 * job['channel_radius_m'])
                for j in range(len(segments) - 1)]
    system.add(source, *segments, *channels)
    system.connect(('syringe', 'a'), ('segment0', 'a'))
    for j, channel in enumerate(channels):
        system.connect((f'segment{j}', 'b'), (channel.label, 'a'))
        system.connect((channel.label, 'b'), (f'segment{j + 1}', 'a'))
    return system, segments


def main():
    job = json.loads(Path(sys.argv[1]).read_text())
    # FONSim prints its progress and, at any verbosity but 0, every Newton residual.
    with contextlib.redirect_stdout(io.StringIO()):
        import fonsim
        from fonsim.fluid.fluid import IdealIncompressible
    fluid = IdealIncompressible(name='water', rho=job['density_kg_per_m3'],
                                mu=job['viscosity_pa_s'])
    arrays, times, cpu = {}, {}, {}
    for k, step in enumerate(job['steps_s']):
        system, segments = network(fonsim, fluid, job)
        with contextlib.redirect_stdout(io.StringIO()):
            simulation = fonsim.Simulation(system, duration=job['duration_s'], step=step,
                                           discretization='backward', verbose=0,
                                           **job.get('options', {}))
            start, cpu_start = time.perf_counter(), time.process_time()
            simulation.run()
            times[str(step)] = time.perf_counter() - start
            cpu[str(step)] = time.process_time() - cpu_start
        arrays[f't{k}'] = np.asarray(simulation.times, dtype=float)
        arrays[f'v{k}'] = np.column_stack([s.get_state('mass') / job['density_kg_per_m3']
                                           for s in segments])
    np.savez(job['out'], **arrays)
    Path(job['out']).with_suffix('.json').write_text(json.dumps(
        {'run_s': times, 'cpu_s': cpu, 'version': importlib.metadata.version('fonsim')}))


if __name__ == '__main__':
    main()

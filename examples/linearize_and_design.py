"""Linearise the plant (Eq. 16-19), close the loop with the paper's PID, and compare a redesign."""
import control

from maglev_cosim.loop.design import discrete_closed_loop
from maglev_cosim.plant.linear import linearize
from maglev_cosim.plant.params import get_params
from maglev_cosim.loop.pid import PID

p = get_params("eq18")
G = linearize(p, 0.0032, i=0.5612)                     # StateSpace: states x, v, i; input u; output y
print("open-loop poles [1/s]:", G.poles().round(2))   # Eq. 19 prints 60.73, -63.12, -333.3
for pid in (PID(), PID(kp=2.5, ki=10.0, kd=0.012)):        # the paper's design, and faster integral action
    T = discrete_closed_loop(p, 0.0032, pid)            # ZOH plant with the discrete PID, dt = 1 ms
    info = control.step_info(T)
    print(f"kp {pid.kp}, ki {pid.ki}, kd {pid.kd}: stable {max(abs(T.poles())) < 1}, "
          f"overshoot {info['Overshoot']:.0f} %, settling {info['SettlingTime'] * 1e3:.0f} ms")

"""The plant FMU in closed loop with plain fmpy and the paper's PID (Eq. 24/25) written out by hand."""
from fmpy import extract, instantiate_fmu, read_model_description

from maglev_cosim import fmu_path

unzipped = extract(str(fmu_path()))
md = read_model_description(unzipped)
vr = {v.name: v.valueReference for v in md.modelVariables}
i0 = (8.3e-3 - 3.2e-3) * (8.4e-3 * 9.81 / 6.9e-6) ** 0.5      # current holding the ball at 3.2 mm (Eq. 8)
u = integral = i0 / 1.5                                         # D/A input giving it: 0.3 A/V * 5 V/MU (Eq. 1, 5)
w, e_prev = 0.2 * (612.3 * 3.2e-3 + 0.0125) + 0.05, 0.0         # reference: 0.05 MU above the start (Eq. 12, 13)
fmu = instantiate_fmu(unzipped, md, fmi_type="CoSimulation")
fmu.setReal([vr["x_start"], vr["i_start"], vr["u"]], [3.2e-3, i0, u])
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.exitInitializationMode()
for k in range(2000):                                           # 2 s at 1 kHz
    y = fmu.getReal([vr["y"]])[0]
    e = w - y
    integral += 2.97 * 1e-3 * e
    u = min(max(2.0 * e + integral + 0.01 * (e - e_prev) / 1e-3, 0.0), 1.0)
    e_prev = e
    fmu.setReal([vr["u"]], [u])
    fmu.doStep(currentCommunicationPoint=k * 1e-3, communicationStepSize=1e-3)
print(f"y = {y:.4f} MU after 2 s (reference {w:.4f} MU)")
fmu.terminate()
fmu.freeInstance()

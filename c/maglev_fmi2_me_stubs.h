/* The FMI 2.0 model-exchange entry points of a co-simulation-only FMU: present so that every
 * importer finds the symbols, each refusing through the includer's
 *     static fmi2Status me_only(fmi2Component c, const char *fn);
 * (its call-sequence guard, then fmi2Error with a logged message). Included once, by the glue
 * (maglev_fmu.c, maglev_pid_fmu.c), after me_only is defined. */
#ifndef MAGLEV_FMI2_ME_STUBS_H
#define MAGLEV_FMI2_ME_STUBS_H

fmi2Status fmi2EnterEventMode(fmi2Component c) { return me_only(c, "fmi2EnterEventMode"); }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    (void)info;
    return me_only(c, "fmi2NewDiscreteStates");
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return me_only(c, "fmi2EnterContinuousTimeMode"); }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint; (void)enterEventMode; (void)terminateSimulation;
    return me_only(c, "fmi2CompletedIntegratorStep");
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    (void)time;
    return me_only(c, "fmi2SetTime");
}
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    (void)x; (void)nx;
    return me_only(c, "fmi2SetContinuousStates");
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    (void)derivatives; (void)nx;
    return me_only(c, "fmi2GetDerivatives");
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators; (void)ni;
    return me_only(c, "fmi2GetEventIndicators");
}
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    (void)x; (void)nx;
    return me_only(c, "fmi2GetContinuousStates");
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    (void)x_nominal; (void)nx;
    return me_only(c, "fmi2GetNominalsOfContinuousStates");
}

#endif

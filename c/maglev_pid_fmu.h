/* The controller FMU's model (build/maglev_pid.fmu, FMI 2.0; build/maglev_pid3.fmu, FMI 3.0): the paper's
 * discrete PID (Eq. 24/25, maglev_pid_step of maglev_replay.c) with a step reference, behind the FMI glue
 * (maglev_fmi_common.h) as the plant is. Its variable table has the plant's MaglevVariable layout, so
 * python/maglev_cosim/plant/model_description.py generates its model descriptions (modelDescription_pid.xml,
 * modelDescription_pid3.xml) from this table too. */
#ifndef MAGLEV_PID_FMU_H
#define MAGLEV_PID_FMU_H

#include "maglev_plant.h"

/* Value references: the FMU's interface, in this order (tests/test_model_description.py). */
typedef enum {
    PID_y = 0,
    PID_w_in,
    PID_u,
    PID_w,
    PID_ts,
    PID_kp,
    PID_ki,
    PID_kd,
    PID_tf,
    PID_u_min,
    PID_u_max,
    PID_anti_windup,
    PID_i_lo,
    PID_i_hi,
    PID_backoff,
    PID_u_hold,
    PID_w0,
    PID_w1,
    PID_t_step,
    MAGLEV_PID_NVARS
} MaglevPidVR;

#define MAGLEV_PID_FIRST_PARAM PID_ts
#define MAGLEV_PID_NPARAMS (MAGLEV_PID_NVARS - PID_ts)

/* One row per value reference, indexed by MaglevPidVR. */
extern MAGLEV_VISIBLE const MaglevVariable maglev_pid_variables[MAGLEV_PID_NVARS];

#endif

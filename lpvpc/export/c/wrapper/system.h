/*
 * system.h -- the contract between a fixed-step discrete-time system and the
 * lpvpc FMI co-simulation wrappers (fmi2_cs.c, fmi3_cs.c).
 *
 * A model provides exactly three C functions (below) and nothing else; the
 * wrappers own all FMI logic (modes, checks, logging, FMU state, memory).
 *
 *   x(k+1) = f(x(k), u(k), p)      sys_update          state update over SYS_STEP s
 *   y(k)   = g(x(k), u(k), p)      sys_output          outputs (direct feedthrough allowed)
 *   x(0)   = x0(p)                 sys_initial_state   initial state from the parameters
 *
 * Units: SI everywhere (rad, rad/s, N m, s), as declared in modelDescription.xml.
 *
 * system_config.h is generated per FMU by lpvpc.export.fmu_build and defines:
 *   SYS_NX, SYS_NU, SYS_NY, SYS_NP        dimensions (ints, may be 0)
 *   SYS_STEP                              internal fixed step in s (double)
 *   SYS_GUID                              GUID / instantiation token (string)
 *   SYS_MODEL_IDENTIFIER                  model identifier (string)
 *   SYS_PARAM_DEFAULTS, SYS_INPUT_DEFAULTS  brace initializer lists of doubles
 *   SYS_OUTPUT_NAMES, SYS_INPUT_NAMES, SYS_PARAM_NAMES  brace lists of strings
 *                                         (used in log messages)
 *
 * Rules for implementations:
 *   - pure functions of their arguments: no global or static mutable data (several
 *     FMU instances run in one process, possibly in parallel threads);
 *   - arrays: x has SYS_NX, u SYS_NU, p SYS_NP, y SYS_NY elements; x_next never
 *     aliases x;
 *   - return 0 on success, nonzero on failure (the wrapper then returns fmi2Error /
 *     fmi3Error and logs which function failed); never print, exit or abort;
 *   - non-finite results need not be detected here: the wrapper checks every
 *     state and output for NaN/inf after each call and reports an error;
 *   - do not depend on libm being linked if avoidable (fmpy's CMake rebuild links
 *     no -lm; the Python process usually provides it anyway).
 *
 * Value references used by the wrappers (same layout for FMI 2 and FMI 3):
 *   0                          time (FMI 3 only; unused in FMI 2)
 *   1 .. NY                    outputs
 *   NY+1 .. NY+NU              inputs
 *   NY+NU+1 .. NY+NU+NP        parameters (fixed: settable before/during initialization)
 */
#ifndef LPVPC_SYSTEM_H
#define LPVPC_SYSTEM_H

#include "system_config.h"

#if defined(__GNUC__) && !defined(_WIN32)
#define SYS_API __attribute__((visibility("hidden")))
#else
#define SYS_API
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* x0 from the parameters. */
SYS_API int sys_initial_state(const double *p, double *x);

/* y(k) = g(x(k), u(k), p): outputs at a communication point with the current inputs. */
SYS_API int sys_output(const double *x, const double *u, const double *p, double *y);

/* x(k+1) = f(x(k), u(k), p): one internal step of SYS_STEP seconds, input held. */
SYS_API int sys_update(const double *x, const double *u, const double *p, double *x_next);

#ifdef __cplusplus
}
#endif

#endif /* LPVPC_SYSTEM_H */

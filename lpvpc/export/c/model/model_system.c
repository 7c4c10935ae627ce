/*
 * model_system.c -- system.h adapter for a model exported by lpvpc.export.exporter.
 *
 * lpvpc.export.exporter generates, with CasADi's CodeGenerator, the file lpvpc_model_casadi.c/.h
 * holding three functions of (state x, inputs u, parameters p), all column vectors:
 *
 *   lpvpc_model_initial(p)       -> x0       initial state
 *   lpvpc_model_output(x, u, p)  -> y        outputs at a sample (direct feedthrough)
 *   lpvpc_model_update(x, u, p)  -> x_next   state after one sample period
 *
 * They come from the same CasADi step as the exported .casadi function, which is built
 * from lpvpc.models.equations (the single definition of the model equations). This file only
 * forwards the system.h calls to them; it knows nothing about the model itself.
 *
 * Work arrays live on the stack (the generated functions are SX functions: no memory
 * objects, no mutable global data), so instances are independent and thread-safe.
 * Units: SI (rad, rad/s, rad/s2, N.m), as declared in modelDescription.xml.
 */
#include "system.h"
#include "lpvpc_model_casadi.h"

#define DIM(n) ((n) > 0 ? (n) : 1)

/* Call a generated function with inputs (in0, in1, in2) (unused ones ignored) and one
 * output. Argument arrays hold at least three inputs and the function's own work size. */
#define CASADI_CALL(fn, in0, in1, in2, out)                                          \
    do {                                                                             \
        const casadi_real *arg_[fn##_SZ_ARG + 3] = {0};                              \
        casadi_real *res_[fn##_SZ_RES + 1] = {0};                                    \
        casadi_int iw_[DIM(fn##_SZ_IW)];                                             \
        casadi_real w_[DIM(fn##_SZ_W)];                                              \
        arg_[0] = (in0);                                                             \
        arg_[1] = (in1);                                                             \
        arg_[2] = (in2);                                                             \
        res_[0] = (out);                                                             \
        return fn(arg_, res_, iw_, w_, 0) == 0 ? 0 : 1;                              \
    } while (0)

SYS_API int sys_initial_state(const double *p, double *x)
{
    CASADI_CALL(lpvpc_model_initial, p, 0, 0, x);
}

SYS_API int sys_output(const double *x, const double *u, const double *p, double *y)
{
    CASADI_CALL(lpvpc_model_output, x, u, p, y);
}

SYS_API int sys_update(const double *x, const double *u, const double *p, double *x_next)
{
    CASADI_CALL(lpvpc_model_update, x, u, p, x_next);
}

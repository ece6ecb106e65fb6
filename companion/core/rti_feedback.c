/* The real-time iteration's feedback as one compiled call (companion/core/rti_compiled.py).
 *
 * Compiled into one library with the CasADi-generated `moved` and `plan` functions of
 * companion/core/rti.py (their names come in as the macros M4_RTI_MOVED and M4_RTI_PLAN) and
 * DAQP's C library (CasADi's wheel ships its headers and libdaqpstat.a). Every array is a
 * numpy buffer the Python side owns; `m4_rti_new` keeps pointers to them.
 *
 * m4_rti_load (the preparation): the Hessian and the rows in their buffers into the DAQP
 * workspace, factorised here, off the critical path (set up at the first load, else
 * update_ldp, as daqp.Model.update does); warm: the next solve starts from the active set of
 * the last one, else from none.
 * m4_rti_feedback (the state arrived): moved (the QP's gradient and bounds straight into
 * DAQP's problem) -> daqp_solve (the step straight into plan's argument) -> plan. Returns
 * M4_RTI_INVALID_INPUT when the sum of x0's and x_ref's entries is not finite (or moved
 * failed), the last load's flag when it failed (-1 before any load), else DAQP's exitflag;
 * the plan is evaluated only when that is > 0 (M4_RTI_PLAN_FAILED when its evaluation fails).
 */

#include <math.h>
#include <stdlib.h>

#include <daqp/api.h>
#include <daqp/utils.h>

typedef long long casadi_int;       /* CasADi's default */

#define M4_RTI_INVALID_INPUT (-100)
#define M4_RTI_PLAN_FAILED (-101)

/* The daqp wheel's pivot tolerance (this DAQP's default: 1e-6). Its soft rows' weight: the wheel
 * (built with SOFT_WEIGHTS) divides its rho_soft (1e-6) by the square of DAQP's scaling of each
 * row (1.35 to 298 for the NMPC's rows along benchmarks.rti's flight: docs/performance.md), so
 * its soft rows are all but hard; this DAQP has one weight for every row, and only one all but
 * hard keeps its plans the wheel's. Along benchmarks.rti's flight the plans differ by up to 11 N
 * with 1e-6, 0.3 N with 1e-8, and 0.03 N at one step with 1e-12 or 1e-16 (the wheel's least
 * hard rows); the built-in flights' truth by 1.2e-7 m at most with 1e-12. */
#define PIVOT_TOL 1e-8
#define RHO_SOFT 1e-12

#define DECLARE(NAME)                                                                               \
    int NAME(const double** arg, double** res, casadi_int* iw, double* w, int mem);                \
    int NAME##_work(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw, casadi_int* sz_w); \
    casadi_int NAME##_n_in(void);                                                                  \
    casadi_int NAME##_n_out(void);
#define EXPAND_DECLARE(NAME) DECLARE(NAME)
EXPAND_DECLARE(M4_RTI_MOVED)
EXPAND_DECLARE(M4_RTI_PLAN)
#define CONCAT(A, B) A##B
#define SUFFIXED(NAME, SUFFIX) CONCAT(NAME, SUFFIX)

typedef struct {
    const double** arg;              /* the inputs' buffers, then the generated code's scratch */
    double** res;
} call;

typedef struct {
    DAQPWorkspace work;
    DAQPProblem qp;
    DAQPResult res;
    int iter_limit;
    int set_up;
    int load_flag;                   /* the last load's: < 0 failed (-1 before the first) */
    call moved, plan;
    casadi_int* iw;
    double* w;
} m4_rti;

/* A call's argument and result arrays: the buffers, then room for what the code needs beyond. */
static int prepare_call(call* c, double* const* arg, double* const* res, casadi_int n_in, casadi_int n_out,
                        int (*size)(casadi_int*, casadi_int*, casadi_int*, casadi_int*), casadi_int* iw,
                        casadi_int* w) {
    casadi_int sz_arg, sz_res, sz_iw, sz_w, i;
    size(&sz_arg, &sz_res, &sz_iw, &sz_w);
    if (sz_iw > *iw) *iw = sz_iw;
    if (sz_w > *w) *w = sz_w;
    c->arg = calloc(sz_arg > n_in ? sz_arg : n_in, sizeof(double*));
    c->res = calloc(sz_res > n_out ? sz_res : n_out, sizeof(double*));
    if (c->arg == NULL || c->res == NULL) return -1;
    for (i = 0; i < n_in; ++i) c->arg[i] = arg[i];
    for (i = 0; i < n_out; ++i) c->res[i] = res[i];
    return 0;
}

void m4_rti_free(m4_rti* f) {
    if (f == NULL) return;
    if (f->set_up) {
        free_daqp_workspace(&f->work);
        free_daqp_ldp(&f->work);
    }
    free(f->moved.arg);
    free(f->moved.res);
    free(f->plan.arg);
    free(f->plan.res);
    free(f->iw);
    free(f->w);
    free(f);
}

/* n variables, m constraints (the first n simple bounds on them); hess (n*n), rows ((m-n)*n)
 * and sense (m: the constraint kinds, none active) kept by the caller; moved_arg/res and
 * plan_arg/res the functions' buffers in their inputs' and outputs' order (moved's first
 * three results the QP's gradient, upper and lower bounds, its fifth the inputs' sum; plan's
 * first argument the step); lam (m) DAQP's duals. NULL when out of memory. */
m4_rti* m4_rti_new(int n, int m, int iter_limit, double* hess, double* rows, int* sense, double* lam,
                   double* const* moved_arg, double* const* moved_res, double* const* plan_arg,
                   double* const* plan_res) {
    m4_rti* f = calloc(1, sizeof(m4_rti));
    casadi_int iw = 1, w = 1;
    if (f == NULL) return NULL;
    if (prepare_call(&f->moved, moved_arg, moved_res, SUFFIXED(M4_RTI_MOVED, _n_in)(),
                     SUFFIXED(M4_RTI_MOVED, _n_out)(), SUFFIXED(M4_RTI_MOVED, _work), &iw, &w) != 0
        || prepare_call(&f->plan, plan_arg, plan_res, SUFFIXED(M4_RTI_PLAN, _n_in)(),
                        SUFFIXED(M4_RTI_PLAN, _n_out)(), SUFFIXED(M4_RTI_PLAN, _work), &iw, &w) != 0
        || (f->iw = malloc(iw * sizeof(casadi_int))) == NULL || (f->w = malloc(w * sizeof(double))) == NULL) {
        m4_rti_free(f);
        return NULL;
    }
    f->load_flag = -1;               /* nothing loaded: the workspace is not set up */
    f->iter_limit = iter_limit;
    f->qp.n = n;
    f->qp.m = m;
    f->qp.ms = n;
    f->qp.H = hess;
    f->qp.A = rows;
    f->qp.f = moved_res[0];
    f->qp.bupper = moved_res[1];
    f->qp.blower = moved_res[2];
    f->qp.sense = sense;
    f->res.x = plan_arg[0];
    f->res.lam = lam;
    return f;
}

int m4_rti_load(m4_rti* f, int warm) {
    int i;
    if (!f->set_up) {
        for (i = 0; i < f->qp.n; ++i) f->qp.f[i] = 0.0;
        for (i = 0; i < f->qp.m; ++i) {
            f->qp.bupper[i] = DAQP_INF;
            f->qp.blower[i] = -DAQP_INF;
        }
        f->load_flag = setup_daqp(&f->qp, &f->work, &f->res.setup_time);   /* freed when it fails */
        if (f->load_flag >= 0) {
            f->work.settings->iter_limit = f->iter_limit;
            f->work.settings->pivot_tol = PIVOT_TOL;
            f->work.settings->rho_soft = RHO_SOFT;
        }
    } else {
        f->load_flag = update_ldp(UPDATE_Rinv | UPDATE_M | (warm ? 0 : UPDATE_sense), &f->work);
        if (f->load_flag < 0) {        /* a Hessian DAQP could not factorise: set up anew next time */
            free_daqp_workspace(&f->work);
            free_daqp_ldp(&f->work);
        }
    }
    f->set_up = f->load_flag >= 0;
    return f->load_flag;
}

/* A simple bound DAQP took for an equality (its bounds were equal: a lost rotor's thrust) back to
 * an inequality once they are not: DAQP marks such bounds, never unmarks them. */
static void release_equalities(m4_rti* f) {
    int i;
    for (i = 0; i < f->qp.ms; ++i) {
        if ((f->work.sense[i] & IMMUTABLE) && !(f->qp.sense[i] & IMMUTABLE)
            && f->qp.bupper[i] - f->qp.blower[i] >= f->work.settings->zero_tol)
            f->work.sense[i] &= ~(ACTIVE | IMMUTABLE);
    }
}

/* The working set from the equalities alone: activate_constraints left the constraints after the
 * singular one inactive, equalities too. */
static void cold_start(m4_rti* f) {
    int i;
    for (i = 0; i < f->qp.m; ++i) {
        if (f->work.sense[i] & IMMUTABLE)
            f->work.sense[i] |= ACTIVE;
        else
            f->work.sense[i] &= ~ACTIVE;
    }
    reset_daqp_workspace(&f->work);
}

int m4_rti_feedback(m4_rti* f) {
    int flag;
    if (M4_RTI_MOVED(f->moved.arg, f->moved.res, f->iw, f->w, 0) != 0 || !isfinite(*f->moved.res[4]))
        return M4_RTI_INVALID_INPUT;
    if (f->load_flag < 0) return f->load_flag;
    release_equalities(f);
    flag = update_ldp(UPDATE_v | UPDATE_d, &f->work);   /* marks the bounds now equal as equalities (active) */
    if (flag < 0) return flag;
    reset_daqp_workspace(&f->work);             /* and the working set from the marks: the last solve's */
    flag = activate_constraints(&f->work);      /* active set and the equalities, factorised anew */
    if (flag == EXIT_OVERDETERMINED_INITIAL) {   /* that set and new equalities singular (a rotor lost) */
        cold_start(f);
        flag = activate_constraints(&f->work);
    }
    if (flag < 0) return flag;
    daqp_solve(&f->res, &f->work);
    if (f->res.exitflag > 0 && M4_RTI_PLAN(f->plan.arg, f->plan.res, f->iw, f->w, 0) != 0)
        return M4_RTI_PLAN_FAILED;
    return f->res.exitflag;
}

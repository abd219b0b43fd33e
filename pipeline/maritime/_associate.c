/*
 * The epoch loop of the track-to-track association (pipeline/maritime/associate.py,
 * ``_assign_ids``) in C: the same decisions, made without a numpy call per site and per
 * epoch, and with gating over a spatial grid instead of dense (rows x candidates)
 * matrices.
 *
 * Why: the numpy loop costs ~0.3 ms per site step in array set-up (a few dozen numpy
 * calls on a handful of rows) and its dense gates grow as rows x candidates: ~60 us per
 * radar report at 100 ships, ~230 us at 1,000 (docs/scale.md). Here one call runs every
 * epoch of a work unit.
 *
 * Same results: every number that decides something is computed with the same
 * operations in the same order as associate.py (gated_d2, the persistence bonus, the
 * eq. 14 candidate state, _predict, the _resolve_ids costs), so the gates and costs are
 * those of the reference (to the last bit but for libm vs numpy, see below). The grid only skips pairs that cannot pass the
 * position gate: d^2 = D^T S^-1 D >= |D|^2 / lambda_max(S) and lambda_max(P_a + P_b) <=
 * lambda_max(P_a) + lambda_max(P_b), so a pair farther apart than
 * sqrt(gate lambda_a) + sqrt(gate lambda_b) fails it; rows or candidates whose
 * covariance is not positive definite are compared with everything. Assignments follow
 * ``associate.assign``: lone matches directly, the rest by the SAME scipy
 * linear_sum_assignment on the same augmented matrix (a Python callback), so ties are
 * broken as in the reference. tests/maritime/test_associate_kernel.py checks that both
 * paths give the same system track of every row.
 *
 * Candidate state (eq. 14): sums of per-channel terms (computed by the caller, 10 per
 * row, the columns associate._Candidates.add accumulates: fuse.Information) turned into a
 * fused state by cand_state(), the formula of fuse.Information.estimate.
 *
 * Cost (associate.gated_d2): the position d^2, plus, with ``velocity`` and when both
 * sides carry speed and course sigmas (rows and candidates do, extrapolated system
 * tracks do not), the velocity d^2 with the covariance of associate.velocity_covariance;
 * the clustering gates on ``gate`` (4 dof with the velocity, else 2), the ids against
 * past system tracks on ``gate_pos`` (2 dof). sin and cos are libm's, as numpy's float64
 * ufuncs (a test compares). The candidate state's atan2 and pow(w, -0.5) are libm's too,
 * where numpy may use its own SIMD versions (SVML on AVX-512 CPUs: 1 ulp apart in ~1% /
 * ~5% of calls here), so a candidate's course and sigmas can differ from the
 * reference's in the last bit: a decision could only differ at an exact tie or exactly
 * on a gate; the ids agree on every test set and on the demo hour.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define NT 10   /* eq. 14 terms per channel */
#define NSTATE 9 /* x, y, Pxx, Pyy, Pxy, V, C, sigma_V, sigma_C */
#define NBUF 14  /* array arguments of assign_ids */
#define TWO_PI (2.0 * 3.141592653589793)
#define PI 3.141592653589793

typedef struct {
    double x, y, pxx, pyy, pxy, v, c;
    double sv, sc; /* sigmas of speed and course (valid when has_vel) */
    int has_vel;
} kin_t;

typedef struct {
    double gate, gate_pos, max_course, max_speed, min_speed, bonus;
    int64_t timeout_ns;
    int form;     /* 0: per-axis sums (1/P_xx, x/P_xx, ...); 1: information form */
    int velocity; /* [association] velocity_cost */
    PyObject *lsa;
} params_t;

/* numpy's np.mod for floats (remainder with the sign of the divisor) */
static double py_mod(double a, double b)
{
    double m = fmod(a, b);
    if (m != 0.0) {
        if ((b < 0) != (m < 0)) m += b;
    } else {
        m = copysign(0.0, b);
    }
    return m;
}

/* associate._d2: (dx, dy) S^-1 (dx, dy)^T, closed-form inverse */
static double quad2(double dx, double dy, double sxx, double syy, double sxy)
{
    return (syy * dx * dx - 2.0 * sxy * dx * dy + sxx * dy * dy) / (sxx * syy - sxy * sxy);
}

/* associate.velocity_covariance for one track: (V_xx, V_yy, V_xy) of v = V (sin C, cos C)
 * and v itself */
static void velocity(const kin_t *k, double min_speed, double *vx, double *vy, double *cov)
{
    double s = sin(k->c), c = cos(k->c);
    double along = k->sv * k->sv, across = (k->v * k->sc) * (k->v * k->sc);
    if (k->v < min_speed && !isnan(across)) /* np.maximum: NaN propagates */
        across = (isnan(along) || along > across) ? along : across;
    cov[0] = along * s * s + across * c * c;
    cov[1] = along * c * c + across * s * s;
    cov[2] = (along - across) * s * c;
    *vx = k->v * s;
    *vy = k->v * c;
}

/* associate.gated_d2 for one pair: d^2 (position, plus velocity when p->velocity and
 * both carry sigmas), or +inf when a gate fails (d^2 below ``gate``, course, speed) */
static double gated_d2(const kin_t *a, const kin_t *b, const params_t *p, double gate)
{
    double dx = a->x - b->x, dy = a->y - b->y;
    double sxx = a->pxx + b->pxx, syy = a->pyy + b->pyy, sxy = a->pxy + b->pxy;
    double d2 = quad2(dx, dy, sxx, syy, sxy);
    double va = a->v, vb = b->v;
    int slow = (va < p->min_speed) && (vb < p->min_speed);
    double dc = fabs(py_mod((a->c - b->c) + PI, TWO_PI) - PI);
    int ok;
    if (p->velocity && a->has_vel && b->has_vel) {
        double ax, ay, bx, by, ca[3], cb[3];
        velocity(a, p->min_speed, &ax, &ay, ca);
        velocity(b, p->min_speed, &bx, &by, cb);
        d2 = d2 + quad2(ax - bx, ay - by, ca[0] + cb[0], ca[1] + cb[1], ca[2] + cb[2]);
    }
    ok = (d2 < gate) && (fabs(va - vb) <= p->max_speed) && (slow || dc <= p->max_course);
    return ok ? d2 : INFINITY;
}

/* associate._Candidates.state for one candidate's sums */
static void cand_state(const double *s, int form, kin_t *k, double *sv, double *sc)
{
    if (form == 0) {
        k->x = s[1] / s[0];
        k->y = s[3] / s[2];
        k->pxx = 1.0 / s[0];
        k->pyy = 1.0 / s[2];
        k->pxy = s[4] / (s[0] * s[2]);
    } else {
        double det = s[0] * s[1] - s[2] * s[2];
        double pxx = s[1] / det, pyy = s[0] / det, pxy = -s[2] / det;
        k->x = pxx * s[3] + pxy * s[4];
        k->y = pxy * s[3] + pyy * s[4];
        k->pxx = pxx;
        k->pyy = pyy;
        k->pxy = pxy;
    }
    k->v = s[6] / s[5];
    k->c = py_mod(atan2(s[8], s[9]), TWO_PI);
    *sv = pow(s[5], -0.5);
    *sc = pow(s[7], -0.5);
    k->sv = *sv;
    k->sc = *sc;
    k->has_vel = 1;
}

/* gate radius sqrt(gate * lambda_max(P)) (slightly widened), or -1 when P is not
 * positive definite or not finite (compare with everything) */
static double gate_radius(const kin_t *k, double gate)
{
    double a = k->pxx, c = k->pyy, b = k->pxy;
    double h = 0.5 * (a - c), lam = 0.5 * (a + c) + sqrt(h * h + b * b);
    if (!(a > 0) || !(c > 0) || !(a * c - b * b > 0) || !isfinite(lam)) return -1.0;
    return sqrt(gate * lam) * (1.0 + 1e-9) + 1e-6;
}

/* 1 when the pair may pass the position gate, 0 when it certainly fails it (farther
 * apart than the sum of the gate radii; a negative radius: compare anyway) */
static int may_gate(const kin_t *a, double ra, const kin_t *b, double rb)
{
    double dx, dy, r;
    if (ra < 0 || rb < 0) return 1;
    dx = a->x - b->x;
    dy = a->y - b->y;
    r = ra + rb;
    return !(dx * dx + dy * dy > r * r);
}

/* -- a grid of points for "which of these can be within r of (x, y)" ----------------- */

typedef struct {
    double x0, y0, cell;
    int64_t nx, ny;
    int64_t *start; /* (nx*ny + 1) CSR offsets */
    int64_t *items; /* point indices, by cell */
    int64_t *big;   /* points compared with everything */
    int64_t n_big, n;
    double rmax;    /* largest radius of the gridded points */
} grid_t;

static void grid_free(grid_t *g)
{
    free(g->start);
    free(g->items);
    free(g->big);
    memset(g, 0, sizeof(*g));
}

/* Points k[0..n) with radii r (<0: big). Cell size: the largest radius of the
 * non-big points, at least 100 m; points with radius > cap go to the big list. */
static int grid_build(grid_t *g, const kin_t *k, const double *r, int64_t n)
{
    const double cap = 3000.0;
    double xmin = INFINITY, xmax = -INFINITY, ymin = INFINITY, ymax = -INFINITY, rmax = 0;
    int64_t i, nbig = 0, ncell;
    memset(g, 0, sizeof(*g));
    g->n = n;
    g->big = malloc(sizeof(int64_t) * (size_t)(n > 0 ? n : 1));
    g->items = malloc(sizeof(int64_t) * (size_t)(n > 0 ? n : 1));
    if (!g->big || !g->items) return -1;
    for (i = 0; i < n; i++) {
        if (r[i] < 0 || r[i] > cap || !isfinite(k[i].x) || !isfinite(k[i].y)) {
            g->big[nbig++] = i;
            continue;
        }
        if (r[i] > rmax) rmax = r[i];
        if (k[i].x < xmin) xmin = k[i].x;
        if (k[i].x > xmax) xmax = k[i].x;
        if (k[i].y < ymin) ymin = k[i].y;
        if (k[i].y > ymax) ymax = k[i].y;
    }
    g->n_big = nbig;
    g->rmax = rmax;
    g->cell = rmax > 100.0 ? rmax : 100.0;
    if (nbig == n) {
        g->nx = g->ny = 0;
        g->start = calloc(1, sizeof(int64_t));
        return g->start ? 0 : -1;
    }
    /* keep the cell count near the point count */
    for (;;) {
        g->nx = (int64_t)floor((xmax - xmin) / g->cell) + 1;
        g->ny = (int64_t)floor((ymax - ymin) / g->cell) + 1;
        if ((double)g->nx * (double)g->ny <= 4.0 * (double)n + 1024.0) break;
        g->cell *= 2.0;
    }
    g->x0 = xmin;
    g->y0 = ymin;
    ncell = g->nx * g->ny;
    g->start = calloc((size_t)ncell + 1, sizeof(int64_t));
    if (!g->start) return -1;
    for (i = 0; i < n; i++) {
        int64_t cx, cy;
        if (r[i] < 0 || r[i] > cap || !isfinite(k[i].x) || !isfinite(k[i].y)) continue;
        cx = (int64_t)((k[i].x - xmin) / g->cell);
        cy = (int64_t)((k[i].y - ymin) / g->cell);
        g->start[cx * g->ny + cy + 1]++;
    }
    for (i = 0; i < ncell; i++) g->start[i + 1] += g->start[i];
    {
        int64_t *fill = malloc(sizeof(int64_t) * (size_t)ncell);
        if (!fill) return -1;
        memcpy(fill, g->start, sizeof(int64_t) * (size_t)ncell);
        for (i = 0; i < n; i++) { /* ascending index within each cell */
            int64_t cx, cy;
            if (r[i] < 0 || r[i] > cap || !isfinite(k[i].x) || !isfinite(k[i].y)) continue;
            cx = (int64_t)((k[i].x - xmin) / g->cell);
            cy = (int64_t)((k[i].y - ymin) / g->cell);
            g->items[fill[cx * g->ny + cy]++] = i;
        }
        free(fill);
    }
    return 0;
}

/* Candidate points that may lie within (radius + rmax) of (x, y), appended to out
 * (unsorted, no duplicates); radius < 0 or a huge search: every point. */
static int64_t grid_query(const grid_t *g, double x, double y, double radius, int64_t *out)
{
    int64_t m = 0, i;
    if (radius >= 0 && isfinite(x) && isfinite(y) && g->nx > 0) {
        double reach = radius + g->rmax;
        int64_t cx0 = (int64_t)floor((x - reach - g->x0) / g->cell);
        int64_t cx1 = (int64_t)floor((x + reach - g->x0) / g->cell);
        int64_t cy0 = (int64_t)floor((y - reach - g->y0) / g->cell);
        int64_t cy1 = (int64_t)floor((y + reach - g->y0) / g->cell);
        if (cx0 < 0) cx0 = 0;
        if (cy0 < 0) cy0 = 0;
        if (cx1 > g->nx - 1) cx1 = g->nx - 1;
        if (cy1 > g->ny - 1) cy1 = g->ny - 1;
        if ((double)(cx1 - cx0 + 1) * (double)(cy1 - cy0 + 1) <= (double)g->n + 16.0) {
            int64_t cx, cy;
            for (cx = cx0; cx <= cx1; cx++)
                for (cy = cy0; cy <= cy1; cy++) {
                    int64_t c = cx * g->ny + cy;
                    for (i = g->start[c]; i < g->start[c + 1]; i++) out[m++] = g->items[i];
                }
            for (i = 0; i < g->n_big; i++) out[m++] = g->big[i];
            return m;
        }
    }
    for (i = 0; i < g->n; i++) out[m++] = i;
    return m;
}

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* -- associate.assign on a sparse cost list ------------------------------------------ */

typedef struct {
    int64_t row, col;
    double cost;
    int persist; /* a persisting pair (its cost carries the continuity bonus) */
} entry_t;

static int cmp_entry(const void *a, const void *b)
{
    const entry_t *x = a, *y = b;
    if (x->row != y->row) return (x->row > y->row) - (x->row < y->row);
    return (x->col > y->col) - (x->col < y->col);
}

/* Entries (row, col, cost) of a (nr, nc) matrix whose other entries are +inf; every
 * given entry is admissible (finite and below its row's miss cost). Writes match[row] =
 * col or -1. Same result as associate.assign(cost, miss).
 *
 * ``forced`` (the clustering step, where a persisting pair costs d^2 - 1000 gate and the
 * other entries lie in [0, gate) unless a covariance is not positive definite): a
 * persisting pair whose row and column have no other persisting entry and no negative
 * entry belongs to EVERY optimal assignment (leaving it out costs more than 998 gates,
 * more than the other entries of its row and column can give back), so it is matched
 * first and its row and column leave the problem; the rest is solved as
 * associate.assign would. The optimum is the same; only when the rest has several
 * optima (exactly equal sums) could the tie be broken differently. */
static int assign_sparse(entry_t *e, int64_t ne, int64_t nr, int64_t nc, const double *miss,
                         const params_t *p, int64_t *match, int forced)
{
    int64_t *row_n = calloc((size_t)nr + 1, sizeof(int64_t));
    int64_t *col_n = calloc((size_t)nc + 1, sizeof(int64_t));
    int64_t *col_of = malloc(sizeof(int64_t) * (size_t)(nr + 1));
    int64_t *row_start = malloc(sizeof(int64_t) * (size_t)(nr + 1));
    int64_t *rest_c_pos = NULL, *rest_r = NULL, *rest_c = NULL;
    double *aug = NULL;
    int64_t i, k = 0, mc = 0;
    int rc = -1;
    if (!row_n || !col_n || !col_of || !row_start) goto done;
    qsort(e, (size_t)ne, sizeof(entry_t), cmp_entry);
    for (i = 0; i < nr; i++) { match[i] = -1; col_of[i] = -1; row_start[i] = -1; }
    if (forced) {
        /* persisting entries per row and column; forced pairs drop out of the problem */
        int64_t w = 0;
        for (i = 0; i < ne; i++) /* counts of persisting entries; a negative other entry
                                  * (non-PD covariance) blocks its row and column */
            if (e[i].persist) { row_n[e[i].row]++; col_n[e[i].col]++; }
            else if (e[i].cost < 0) { row_n[e[i].row] += 2; col_n[e[i].col] += 2; }
        for (i = 0; i < ne; i++)
            if (e[i].persist && row_n[e[i].row] == 1 && col_n[e[i].col] == 1)
                match[e[i].row] = e[i].col;
        memset(col_n, 0, sizeof(int64_t) * (size_t)(nc + 1));
        for (i = 0; i < ne; i++)
            if (match[e[i].row] >= 0 && match[e[i].row] == e[i].col) col_n[e[i].col] = 1;
        for (i = 0; i < ne; i++) /* keep entries of free rows to free columns */
            if (match[e[i].row] < 0 && !col_n[e[i].col]) e[w++] = e[i];
        ne = w;
        memset(row_n, 0, sizeof(int64_t) * (size_t)(nr + 1));
        memset(col_n, 0, sizeof(int64_t) * (size_t)(nc + 1));
    }
    for (i = 0; i < ne; i++) {
        if (row_n[e[i].row] == 0) { col_of[e[i].row] = e[i].col; row_start[e[i].row] = i; }
        row_n[e[i].row]++;
        col_n[e[i].col]++;
    }
    rest_r = malloc(sizeof(int64_t) * (size_t)(nr + 1));
    rest_c_pos = malloc(sizeof(int64_t) * (size_t)(nc + 1));
    rest_c = malloc(sizeof(int64_t) * (size_t)(nc + 1));
    if (!rest_r || !rest_c_pos || !rest_c) goto done;
    for (i = 0; i < nc; i++) rest_c_pos[i] = -1;
    for (i = 0; i < nr; i++) {
        if (row_n[i] == 0 || match[i] >= 0) continue;
        if (row_n[i] == 1 && col_n[col_of[i]] == 1) {
            match[i] = col_of[i];
            continue;
        }
        rest_r[k++] = i;
    }
    if (k == 0) { rc = 0; goto done; }
    /* columns admissible for some rest row, ascending */
    for (i = 0; i < ne; i++) {
        int64_t r = e[i].row;
        if (row_n[r] > 0 && match[r] < 0 && rest_c_pos[e[i].col] < 0) {
            rest_c_pos[e[i].col] = 0;
        }
    }
    for (i = 0; i < nc; i++)
        if (rest_c_pos[i] == 0) { rest_c_pos[i] = mc; rest_c[mc++] = i; }
    {
        int64_t w = mc + k, j;
        PyObject *bytes, *res;
        Py_buffer out;
        aug = malloc(sizeof(double) * (size_t)(k * w));
        if (!aug) goto done;
        for (i = 0; i < k * w; i++) aug[i] = INFINITY;
        for (j = 0; j < k; j++) {
            int64_t r = rest_r[j];
            for (i = row_start[r]; i < row_start[r] + row_n[r]; i++)
                aug[j * w + rest_c_pos[e[i].col]] = e[i].cost;
            aug[j * w + mc + j] = miss[r];
        }
        bytes = PyBytes_FromStringAndSize((const char *)aug, (Py_ssize_t)(sizeof(double) * k * w));
        if (!bytes) goto done;
        res = PyObject_CallFunction(p->lsa, "Onn", bytes, (Py_ssize_t)k, (Py_ssize_t)w);
        Py_DECREF(bytes);
        if (!res) goto done;
        if (PyObject_GetBuffer(res, &out, PyBUF_SIMPLE) < 0) { Py_DECREF(res); goto done; }
        if (out.len != (Py_ssize_t)(sizeof(int64_t) * k)) {
            PyErr_SetString(PyExc_ValueError, "lsa callback returned a wrong length");
            PyBuffer_Release(&out);
            Py_DECREF(res);
            goto done;
        }
        for (j = 0; j < k; j++) {
            int64_t col = ((const int64_t *)out.buf)[j];
            if (col < mc) match[rest_r[j]] = rest_c[col];
        }
        PyBuffer_Release(&out);
        Py_DECREF(res);
    }
    rc = 0;
done:
    free(row_n);
    free(col_n);
    free(col_of);
    free(row_start);
    free(rest_r);
    free(rest_c_pos);
    free(rest_c);
    free(aug);
    if (rc < 0 && !PyErr_Occurred()) PyErr_NoMemory();
    return rc;
}

/* -- entry list that grows ------------------------------------------------------------- */

typedef struct {
    entry_t *e;
    int64_t n, cap;
} elist_t;

static int elist_push(elist_t *l, int64_t row, int64_t col, double cost, int persist)
{
    if (l->n == l->cap) {
        int64_t cap = l->cap ? 2 * l->cap : 1024;
        entry_t *e = realloc(l->e, sizeof(entry_t) * (size_t)cap);
        if (!e) return -1;
        l->e = e;
        l->cap = cap;
    }
    l->e[l->n].row = row;
    l->e[l->n].col = col;
    l->e[l->n].cost = cost;
    l->e[l->n].persist = persist;
    l->n++;
    return 0;
}

/* -- the epoch loop -------------------------------------------------------------------- */

typedef struct {
    int64_t *sys_seen;
    double *sys_state;
    int64_t n_sys, cap;
} sysmem_t;

static int64_t sys_grow(sysmem_t *m, int64_t k)
{
    int64_t first = m->n_sys;
    if (m->n_sys + k > m->cap) {
        int64_t cap = 2 * m->cap > m->n_sys + k ? 2 * m->cap : m->n_sys + k;
        int64_t *seen = realloc(m->sys_seen, sizeof(int64_t) * (size_t)cap);
        double *st;
        if (!seen) return -1;
        m->sys_seen = seen;
        st = realloc(m->sys_state, sizeof(double) * NSTATE * (size_t)cap);
        if (!st) return -1;
        m->sys_state = st;
        m->cap = cap;
    }
    m->n_sys += k;
    return first;
}

/* associate._predict for one system track */
static void predict(const sysmem_t *m, int64_t s, int64_t t_ns, kin_t *k)
{
    const double *st = m->sys_state + NSTATE * s;
    double dt = (double)(t_ns - m->sys_seen[s]) / 1e9;
    double V = st[5], C = st[6], sn = sin(C), cs = cos(C);
    double along = (st[7] * dt) * (st[7] * dt) + 0.0;
    double across = (st[8] * V * dt) * (st[8] * V * dt);
    k->x = st[0] + V * dt * sn;
    k->y = st[1] + V * dt * cs;
    k->pxx = st[2] + (along * sn * sn + across * cs * cs);
    k->pyy = st[3] + (along * cs * cs + across * sn * sn);
    k->pxy = st[4] + ((along - across) * sn * cs);
    k->v = V;
    k->c = C;
    k->has_vel = 0; /* a stale velocity: ids against past tracks stay on position */
}

static int run(int64_t n, const int64_t *t, const int64_t *site, const int64_t *key,
               const double *col[9], const double *terms, int64_t n_keys, int64_t n_sites,
               const params_t *p, int64_t *out)
{
    int64_t *key_sys = malloc(sizeof(int64_t) * (size_t)(n_keys + 1));
    int64_t *key_seen = malloc(sizeof(int64_t) * (size_t)(n_keys + 1));
    sysmem_t mem = {0};
    /* per-epoch buffers, sized for the largest epoch */
    int64_t maxm = 0, a, b, i;
    double *sums = NULL, *sv = NULL, *sc = NULL, *rad = NULL, *miss = NULL, *live_rad = NULL;
    int64_t *prev_ids = NULL, *member = NULL, *prev = NULL, *found = NULL, *ids = NULL;
    int64_t *match = NULL, *live = NULL, *live_pos = NULL, *vote_l = NULL;
    char *dirty = NULL;
    kin_t *ck = NULL, *rk = NULL, *lk = NULL;
    elist_t el = {0};
    int rc = -1;
    if (!key_sys || !key_seen) goto done;
    for (i = 0; i < n_keys; i++) { key_sys[i] = -1; key_seen[i] = INT64_MIN / 2; }
    mem.cap = n_keys > 16 ? n_keys : 16;
    mem.sys_seen = calloc((size_t)mem.cap, sizeof(int64_t));
    mem.sys_state = calloc((size_t)mem.cap * NSTATE, sizeof(double));
    if (!mem.sys_seen || !mem.sys_state) goto done;
    for (a = 0; a < n; a = b) {
        for (b = a; b < n && t[b] == t[a]; b++) {}
        if (b - a > maxm) maxm = b - a;
    }
    sums = malloc(sizeof(double) * NT * (size_t)(maxm + 1));
    prev_ids = malloc(sizeof(int64_t) * (size_t)(n_sites * (maxm + 1)));
    member = malloc(sizeof(int64_t) * (size_t)(maxm + 1));
    prev = malloc(sizeof(int64_t) * (size_t)(maxm + 1));
    found = malloc(sizeof(int64_t) * (size_t)(maxm + mem.cap + 1));
    ids = malloc(sizeof(int64_t) * (size_t)(maxm + 1));
    match = malloc(sizeof(int64_t) * (size_t)(maxm + 1));
    sv = malloc(sizeof(double) * (size_t)(maxm + 1));
    sc = malloc(sizeof(double) * (size_t)(maxm + 1));
    rad = malloc(sizeof(double) * (size_t)(maxm + 1));
    miss = malloc(sizeof(double) * (size_t)(maxm + 1));
    ck = malloc(sizeof(kin_t) * (size_t)(maxm + 1));
    rk = malloc(sizeof(kin_t) * (size_t)(maxm + 1));
    vote_l = malloc(sizeof(int64_t) * (size_t)(n_sites + 1));
    dirty = malloc((size_t)(maxm + 1));
    if (!dirty || !sums || !prev_ids || !member || !prev || !found || !ids || !match || !sv || !sc ||
        !rad || !miss || !ck || !rk || !vote_l)
        goto done;
    for (a = 0; a < n; a = b) {
        int64_t m, nc = 0, s0, s1, tn = t[a];
        for (b = a; b < n && t[b] == tn; b++) {}
        m = b - a;
        for (i = 0; i < m; i++) {
            int64_t kk = key[a + i];
            prev[i] = key_seen[kk] >= tn - p->timeout_ns ? key_sys[kk] : -1;
            member[i] = -1;
            rk[i].x = col[0][a + i];
            rk[i].y = col[1][a + i];
            rk[i].pxx = col[2][a + i];
            rk[i].pyy = col[3][a + i];
            rk[i].pxy = col[4][a + i];
            rk[i].v = col[5][a + i];
            rk[i].c = col[6][a + i];
            rk[i].sv = col[7][a + i];
            rk[i].sc = col[8][a + i];
            rk[i].has_vel = 1;
        }
        /* sequential clustering over the sites of the epoch (associate._cluster_epoch) */
        for (s0 = 0; s0 < m; s0 = s1) {
            int64_t s = site[a + s0];
            for (s1 = s0; s1 < m && site[a + s1] == s; s1++) {}
            if (nc > 0) {
                grid_t g;
                for (i = 0; i < nc; i++) {
                    if (!dirty[i]) continue; /* state unchanged since the last site */
                    cand_state(sums + NT * i, p->form, &ck[i], &sv[i], &sc[i]);
                    rad[i] = gate_radius(&ck[i], p->gate);
                    dirty[i] = 0;
                }
                if (grid_build(&g, ck, rad, nc) < 0) { grid_free(&g); goto done; }
                el.n = 0;
                for (i = s0; i < s1; i++) {
                    double rr = gate_radius(&rk[i], p->gate);
                    int64_t q = grid_query(&g, rk[i].x, rk[i].y, rr, found), j;
                    for (j = 0; j < q; j++) {
                        int64_t c = found[j], h;
                        double d2;
                        int persist = 0;
                        if (!may_gate(&rk[i], rr, &ck[c], rad[c])) continue;
                        d2 = gated_d2(&rk[i], &ck[c], p, p->gate);
                        if (!isfinite(d2)) continue;
                        if (prev[i] >= 0) {
                            for (h = 0; h < n_sites; h++)
                                if (prev_ids[c * n_sites + h] == prev[i]) break;
                            if (h < n_sites) { d2 = d2 - p->bonus * p->gate; persist = 1; }
                        }
                        if (!(d2 < p->gate)) continue;
                        if (elist_push(&el, i - s0, c, d2, persist) < 0) {
                            grid_free(&g);
                            goto done;
                        }
                    }
                }
                grid_free(&g);
                for (i = 0; i < s1 - s0; i++) miss[i] = p->gate;
                if (assign_sparse(el.e, el.n, s1 - s0, nc, miss, p, match, 1) < 0) goto done;
                for (i = s0; i < s1; i++) member[i] = match[i - s0];
            }
            for (i = s0; i < s1; i++) /* fresh candidates, in row order */
                if (member[i] < 0) {
                    int64_t h;
                    member[i] = nc;
                    memset(sums + NT * nc, 0, sizeof(double) * NT);
                    for (h = 0; h < n_sites; h++) prev_ids[nc * n_sites + h] = -1;
                    nc++;
                }
            for (i = s0; i < s1; i++) {
                int64_t h, c = member[i];
                const double *tr = terms + NT * (a + i);
                for (h = 0; h < NT; h++) sums[NT * c + h] += tr[h];
                prev_ids[c * n_sites + s] = prev[i];
                dirty[c] = 1;
            }
        }
        /* system ids of the candidates (associate._resolve_ids) */
        {
            int64_t n_live = 0, l;
            grid_t g;
            live = realloc(live, sizeof(int64_t) * (size_t)(mem.n_sys + 1));
            live_pos = realloc(live_pos, sizeof(int64_t) * (size_t)(mem.n_sys + 1));
            lk = realloc(lk, sizeof(kin_t) * (size_t)(mem.n_sys + 1));
            live_rad = realloc(live_rad, sizeof(double) * (size_t)(mem.n_sys + 1));
            if (!live || !live_pos || !lk || !live_rad) goto done;
            found = realloc(found, sizeof(int64_t) * (size_t)(maxm + mem.n_sys + 1));
            if (!found) goto done;
            for (l = 0; l < mem.n_sys; l++) {
                live_pos[l] = -1;
                if (mem.sys_seen[l] >= tn - p->timeout_ns) {
                    live_pos[l] = n_live;
                    live[n_live] = l;
                    predict(&mem, l, tn, &lk[n_live]);
                    live_rad[n_live] = gate_radius(&lk[n_live], p->gate_pos);
                    n_live++;
                }
            }
            for (i = 0; i < nc; i++)
                if (dirty[i]) {
                    cand_state(sums + NT * i, p->form, &ck[i], &sv[i], &sc[i]);
                    dirty[i] = 0;
                }
            if (grid_build(&g, lk, live_rad, n_live) < 0) { grid_free(&g); goto done; }
            el.n = 0;
            for (i = 0; i < nc; i++) {
                int64_t h, nv = 0, orphan = 1;
                for (h = 0; h < n_sites; h++) {
                    int64_t ps = prev_ids[i * n_sites + h], u;
                    if (ps >= 0) orphan = 0;
                    if (ps < 0 || live_pos[ps] < 0) continue;
                    for (u = 0; u < nv; u++)
                        if (vote_l[u] == live_pos[ps]) break;
                    if (u == nv) vote_l[nv++] = live_pos[ps];
                }
                if (!orphan) {
                    int64_t u;
                    for (u = 0; u < nv; u++) {
                        int64_t lp = vote_l[u], votes = 0;
                        double d2 = gated_d2(&ck[i], &lk[lp], p, p->gate_pos), q, rank;
                        for (h = 0; h < n_sites; h++)
                            if (prev_ids[i * n_sites + h] == live[lp]) votes++;
                        rank = (double)lp / (double)(n_live > 1 ? n_live : 1);
                        q = d2 / p->gate_pos;
                        if (!(q < 1.0)) q = 1.0;
                        if (elist_push(&el, i, lp, -10.0 * (double)votes + rank + 0.01 * q, 0) < 0) {
                            grid_free(&g);
                            goto done;
                        }
                    }
                } else {
                    double rr = gate_radius(&ck[i], p->gate_pos);
                    int64_t q = grid_query(&g, ck[i].x, ck[i].y, rr, found), j;
                    for (j = 0; j < q; j++) {
                        double d2;
                        if (!may_gate(&ck[i], rr, &lk[found[j]], live_rad[found[j]])) continue;
                        d2 = gated_d2(&ck[i], &lk[found[j]], p, p->gate_pos);
                        if (!isfinite(d2)) continue;
                        d2 = d2 / p->gate_pos - 1.0;
                        if (!(d2 < 0.0)) continue;
                        if (elist_push(&el, i, found[j], d2, 0) < 0) { grid_free(&g); goto done; }
                    }
                }
            }
            grid_free(&g);
            for (i = 0; i < nc; i++) miss[i] = 0.0;
            if (assign_sparse(el.e, el.n, nc, n_live, miss, p, match, 0) < 0) goto done;
            {
                int64_t fresh = 0, first;
                for (i = 0; i < nc; i++) {
                    ids[i] = match[i] >= 0 ? live[match[i]] : -1;
                    if (ids[i] < 0) fresh++;
                }
                first = sys_grow(&mem, fresh);
                if (first < 0) goto done;
                for (i = 0; i < nc; i++)
                    if (ids[i] < 0) ids[i] = first++;
            }
        }
        for (i = 0; i < m; i++) {
            int64_t kk = key[a + i];
            out[a + i] = ids[member[i]];
            key_sys[kk] = out[a + i];
            key_seen[kk] = tn;
        }
        for (i = 0; i < nc; i++) {
            double *st = mem.sys_state + NSTATE * ids[i];
            mem.sys_seen[ids[i]] = tn;
            st[0] = ck[i].x;
            st[1] = ck[i].y;
            st[2] = ck[i].pxx;
            st[3] = ck[i].pyy;
            st[4] = ck[i].pxy;
            st[5] = ck[i].v;
            st[6] = ck[i].c;
            st[7] = sv[i];
            st[8] = sc[i];
        }
    }
    rc = 0;
done:
    free(key_sys);
    free(key_seen);
    free(mem.sys_seen);
    free(mem.sys_state);
    free(sums);
    free(prev_ids);
    free(member);
    free(prev);
    free(found);
    free(ids);
    free(match);
    free(sv);
    free(sc);
    free(rad);
    free(miss);
    free(live_rad);
    free(ck);
    free(rk);
    free(lk);
    free(live);
    free(live_pos);
    free(vote_l);
    free(dirty);
    free(el.e);
    if (rc < 0 && !PyErr_Occurred()) PyErr_NoMemory();
    return rc;
}

/* -- Python entry point --------------------------------------------------------------- */

PyDoc_STRVAR(assign_ids_doc,
"assign_ids(t, site, key, x, y, P_xx, P_yy, P_xy, speed, course, sigma_speed,\n"
"           sigma_course, terms, out, n_keys, n_sites, gate, gate_pos, max_course,\n"
"           max_speed, min_speed, bonus, timeout_ns, form, velocity, lsa)\n"
"\n"
"The epoch loop of associate._assign_ids. Arrays (any object with the buffer protocol,\n"
"C-contiguous): t, site, key int64 (n,), rows sorted by (t, site, local track); the\n"
"kinematics float64 (n,); terms float64 (n, 10); out int64 (n,) receives each row's system\n"
"index. ``gate``: the clustering's d^2 gate, ``gate_pos``: the position gate of the ids\n"
"against past system tracks; ``velocity``: 1 = position + velocity cost in the\n"
"clustering. ``form`` 0/1: the eq. 14 sums per axis / in information form. ``lsa(cost, k, m)``:\n"
"cost bytes of a (k, m) float64 matrix -> bytes of k int64 columns (the row-wise result\n"
"of scipy.optimize.linear_sum_assignment).");

static int get(PyObject *o, Py_buffer *v, Py_ssize_t n, Py_ssize_t itemsize, int writable,
               const char *name)
{
    if (PyObject_GetBuffer(o, v, writable ? PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS
                                          : PyBUF_C_CONTIGUOUS) < 0)
        return -1;
    if (v->len != n * itemsize) {
        PyErr_Format(PyExc_ValueError, "%s: %zd bytes, expected %zd", name, v->len, n * itemsize);
        PyBuffer_Release(v);
        return -1;
    }
    return 0;
}

static PyObject *assign_ids(PyObject *self, PyObject *args)
{
    PyObject *o[NBUF], *lsa;
    Py_buffer v[NBUF];
    const char *names[NBUF] = {"t", "site", "key", "x", "y", "P_xx", "P_yy", "P_xy", "speed",
                               "course", "sigma_speed", "sigma_course", "terms", "out"};
    long long n_keys, n_sites, timeout_ns;
    double gate, gate_pos, max_course, max_speed, min_speed, bonus;
    int form, vel, got = 0, rc;
    Py_ssize_t n;
    params_t p;
    const double *cols[9];
    (void)self;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOLLddddddLiiO", &o[0], &o[1], &o[2], &o[3],
                          &o[4], &o[5], &o[6], &o[7], &o[8], &o[9], &o[10], &o[11], &o[12],
                          &o[13], &n_keys, &n_sites, &gate, &gate_pos, &max_course, &max_speed,
                          &min_speed, &bonus, &timeout_ns, &form, &vel, &lsa))
        return NULL;
    if (PyObject_GetBuffer(o[0], &v[0], PyBUF_C_CONTIGUOUS) < 0) return NULL;
    n = v[0].len / 8;
    PyBuffer_Release(&v[0]);
    for (got = 0; got < NBUF; got++) {
        Py_ssize_t items = got == NBUF - 2 ? n * NT : n;
        if (get(o[got], &v[got], items, 8, got == NBUF - 1, names[got]) < 0) goto fail;
    }
    p.gate = gate;
    p.gate_pos = gate_pos;
    p.velocity = vel;
    p.max_course = max_course;
    p.max_speed = max_speed;
    p.min_speed = min_speed;
    p.bonus = bonus;
    p.timeout_ns = timeout_ns;
    p.form = form;
    p.lsa = lsa;
    for (int j = 0; j < 9; j++) cols[j] = v[3 + j].buf;
    rc = run(n, v[0].buf, v[1].buf, v[2].buf, cols, v[NBUF - 2].buf, n_keys, n_sites, &p,
             v[NBUF - 1].buf);
    for (int j = 0; j < NBUF; j++) PyBuffer_Release(&v[j]);
    if (rc < 0) return NULL;
    Py_RETURN_NONE;
fail:
    for (int j = 0; j < got; j++) PyBuffer_Release(&v[j]);
    return NULL;
}

static PyMethodDef methods[] = {
    {"assign_ids", assign_ids, METH_VARARGS, assign_ids_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_associate",
    "The track-to-track association's epoch loop (see _associate.c).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__associate(void)
{
    return PyModule_Create(&module);
}

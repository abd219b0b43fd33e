/*
 * The arithmetic of the ship motion model's transition (pipeline/filters/particle.py,
 * ``propagate_speed_course``, eq. 3 of the distributed maritime observation paper) in one
 * pass over the particles.
 *
 * Why: the numpy version makes ~15 passes over (G, N) temporaries, and numpy's float64
 * sin and cos are libm's, element by element; at 2,000 particles per gap they were a
 * quarter of a dense hour's gaps unit (docs/scale.md). Here each particle is read once,
 * and sin and cos of the same angle come from one sincos() call.
 *
 * Same results, to the last bit: the random draws stay numpy's (the caller draws them,
 * in the same order, and applies the turn jumps), and every number is computed with the
 * operations and in the order numpy evaluates the Python expressions (built with
 * -ffp-contract=off, so no fused multiply-add). glibc's sincos gives sin's and cos's
 * results. tests/filters/test_particle_kernel.py compares the two paths.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h> /* first; it defines _GNU_SOURCE, which declares sincos() in math.h */

#include <math.h>

static const double TWO_PI = 2.0 * 3.141592653589793;

/* np.maximum(a, 0.0) and np.minimum(a, b) propagate NaN */
static inline double nmax0(double a) { return (isnan(a) || a > 0.0) ? a : 0.0; }
static inline double nmin(double a, double b) { return (isnan(a) || a < b) ? a : b; }

static void propagate(Py_ssize_t G, Py_ssize_t N, const double *particles,
                      const double *course0, const double *normals, const double *dt_s,
                      double *out, double course_noise, double speed_noise, double max_speed)
{
    for (Py_ssize_t g = 0; g < G; g++) {
        const double dt = dt_s[g], sq = sqrt(nmax0(dt));
        const double cs = course_noise * sq, ss = speed_noise * sq;
        for (Py_ssize_t n = 0; n < N; n++) {
            const Py_ssize_t i = g * N + n;
            const double *p = particles + 4 * i;
            double *o = out + 4 * i;
            const double c0 = course0[i], v0 = p[2];
            const double c1 = c0 + cs * normals[2 * i];
            const double v1 = nmin(fabs(v0 + ss * normals[2 * i + 1]), max_speed);
            const double cm = 0.5 * (c0 + c1), vm = 0.5 * (v0 + v1);
            double s, c;
            sincos(cm, &s, &c);
            o[0] = p[0] + vm * dt * s;
            o[1] = p[1] + vm * dt * c;
            o[2] = v1;
            o[3] = c1 - TWO_PI * floor(c1 / TWO_PI);
        }
    }
}

static int get(PyObject *o, Py_buffer *v, Py_ssize_t n, int writable, const char *name)
{
    if (PyObject_GetBuffer(o, v, writable ? PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS
                                          : PyBUF_C_CONTIGUOUS) < 0)
        return -1;
    if (v->len != n * (Py_ssize_t)sizeof(double)) {
        PyErr_Format(PyExc_ValueError, "%s: %zd bytes, expected %zd", name, v->len,
                     n * (Py_ssize_t)sizeof(double));
        PyBuffer_Release(v);
        return -1;
    }
    return 0;
}

PyDoc_STRVAR(propagate_doc,
"propagate_speed_course(particles, course0, normals, dt_s, out, course_noise, speed_noise,\n"
"max_speed)\n\n"
"particles (G, N, 4), course0 (G, N): the courses after the turn jumps, normals (G, N, 2),\n"
"dt_s (G,): float64, C-contiguous; writes the propagated particles into out (G, N, 4).");

static PyObject *propagate_speed_course(PyObject *self, PyObject *args)
{
    PyObject *o[5];
    Py_buffer v[5];
    const char *names[5] = {"particles", "course0", "normals", "dt_s", "out"};
    Py_ssize_t G, N, sizes[5];
    double course_noise, speed_noise, max_speed;
    int got;
    (void)self;
    if (!PyArg_ParseTuple(args, "nnOOOOOddd", &G, &N, &o[0], &o[1], &o[2], &o[3], &o[4],
                          &course_noise, &speed_noise, &max_speed))
        return NULL;
    sizes[0] = G * N * 4; sizes[1] = G * N; sizes[2] = G * N * 2; sizes[3] = G;
    sizes[4] = G * N * 4;
    for (got = 0; got < 5; got++)
        if (get(o[got], &v[got], sizes[got], got == 4, names[got]) < 0) goto fail;
    Py_BEGIN_ALLOW_THREADS
    propagate(G, N, v[0].buf, v[1].buf, v[2].buf, v[3].buf, v[4].buf, course_noise,
              speed_noise, max_speed);
    Py_END_ALLOW_THREADS
    for (int j = 0; j < 5; j++) PyBuffer_Release(&v[j]);
    Py_RETURN_NONE;
fail:
    for (int j = 0; j < got; j++) PyBuffer_Release(&v[j]);
    return NULL;
}

static PyMethodDef methods[] = {
    {"propagate_speed_course", propagate_speed_course, METH_VARARGS, propagate_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_particle",
    "The ship motion model's transition in one pass (see _particle.c).", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__particle(void)
{
    return PyModule_Create(&module);
}

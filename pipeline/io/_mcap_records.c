/*
 * The records of one decompressed MCAP chunk, walked in C: per Message record its
 * channel id, log time and payload span; per other record its opcode and body span.
 *
 * Why: locating ~1,000 messages per chunk with numpy over the MessageIndex costs
 * ~0.4 ms per chunk in array set-up (docs/ingest_speed.md); walking the record headers
 * in C costs a few microseconds and checks the whole chunk (the index is not needed).
 *
 * MCAP record layout (mcap.dev/spec): opcode u8 | length u64 | body; a Message body is
 * channel_id u16 | sequence u32 | log_time u64 | publish_time u64 | data.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <string.h>

#define OP_MESSAGE 0x05
#define MSG_HEAD 22 /* channel_id, sequence, log_time, publish_time */

static uint64_t le64(const uint8_t *p)
{
    uint64_t v;
    memcpy(&v, p, 8); /* x86-64 and aarch64 are little-endian, as MCAP is */
    return v;
}

PyDoc_STRVAR(walk_doc,
"walk_chunk(records) -> (channel, log_time, start, end, others)\n"
"\n"
"Walk the records of a decompressed chunk. ``channel``, ``log_time``, ``start``, ``end``:\n"
"bytes holding int64 arrays, one entry per Message record in order (payload span\n"
"[start, end) in ``records``); ``others``: (opcode, body start, body end) of every other\n"
"record. Raises ValueError naming the byte where the records stop making sense (a\n"
"header cut short, a record running past the end, a message shorter than its header).");

static PyObject *walk_chunk(PyObject *self, PyObject *arg)
{
    Py_buffer v;
    const uint8_t *buf;
    Py_ssize_t n, pos, count = 0, i = 0;
    PyObject *ch = NULL, *lt = NULL, *st = NULL, *en = NULL, *others = NULL;
    (void)self;
    if (PyObject_GetBuffer(arg, &v, PyBUF_SIMPLE) < 0) return NULL;
    buf = v.buf;
    n = v.len;
    /* pass 1: check the structure, count the messages (without the GIL: it is called in
     * the fetch thread right after decompression, while the chunk is in cache) */
    {
        int bad = 0;
        Py_BEGIN_ALLOW_THREADS
        for (pos = 0; pos < n;) {
            uint64_t length;
            if (n - pos < 9) { bad = 1; break; }
            length = le64(buf + pos + 1);
            if (length > (uint64_t)(n - pos - 9)) { bad = 2; break; }
            if (buf[pos] == OP_MESSAGE) {
                if (length < MSG_HEAD) { bad = 3; break; }
                count++;
            }
            pos += 9 + (Py_ssize_t)length;
        }
        Py_END_ALLOW_THREADS
        if (bad) {
            PyErr_Format(PyExc_ValueError,
                         bad == 1 ? "record header cut at chunk byte %zd"
                         : bad == 2 ? "record at chunk byte %zd runs past the chunk end"
                                    : "message record too short at chunk byte %zd",
                         pos);
            goto fail;
        }
    }
    ch = PyBytes_FromStringAndSize(NULL, 8 * count);
    lt = PyBytes_FromStringAndSize(NULL, 8 * count);
    st = PyBytes_FromStringAndSize(NULL, 8 * count);
    en = PyBytes_FromStringAndSize(NULL, 8 * count);
    others = PyList_New(0);
    if (!ch || !lt || !st || !en || !others) goto fail;
    {
        int64_t *c = (int64_t *)PyBytes_AS_STRING(ch), *t = (int64_t *)PyBytes_AS_STRING(lt);
        int64_t *s = (int64_t *)PyBytes_AS_STRING(st), *e = (int64_t *)PyBytes_AS_STRING(en);
        for (pos = 0; pos < n;) {
            Py_ssize_t end = pos + 9 + (Py_ssize_t)le64(buf + pos + 1);
            if (buf[pos] == OP_MESSAGE) {
                c[i] = (int64_t)(buf[pos + 9] | (buf[pos + 10] << 8));
                t[i] = (int64_t)le64(buf + pos + 9 + 6);
                s[i] = pos + 9 + MSG_HEAD;
                e[i] = end;
                i++;
            } else {
                PyObject *rec = Py_BuildValue("(inn)", (int)buf[pos], pos + 9, end);
                if (!rec || PyList_Append(others, rec) < 0) {
                    Py_XDECREF(rec);
                    goto fail;
                }
                Py_DECREF(rec);
            }
            pos = end;
        }
    }
    PyBuffer_Release(&v);
    return Py_BuildValue("(NNNNN)", ch, lt, st, en, others);
fail:
    PyBuffer_Release(&v);
    Py_XDECREF(ch);
    Py_XDECREF(lt);
    Py_XDECREF(st);
    Py_XDECREF(en);
    Py_XDECREF(others);
    return NULL;
}

static PyMethodDef methods[] = {
    {"walk_chunk", walk_chunk, METH_O, walk_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_mcap_records", "MCAP chunk record walker (see _mcap_records.c).",
    -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__mcap_records(void)
{
    return PyModule_Create(&module);
}

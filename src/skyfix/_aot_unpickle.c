/* Linked into each module skyfix.aot builds (numba.pycc): a memo in front of numba_unpickle.
 *
 * A compiled function that hands Python an object numba cannot build from constants (an array
 * returned: its Python type; an exception's class and arguments) unpickles it from bytes the
 * module carries, on every call. numba's JIT memoises that by the bytes' address
 * (numba.core.serialize._numba_unpickle); the ahead-of-time branch of numba/_helperlib.c calls
 * pickle.loads each time, about 1 µs an array returned. skyfix.aot points the compiled code at
 * skyfix_unpickle instead, which keeps what it unpickled by the same address, as the JIT does:
 * the objects are immutable constants of the module (a type, a dtype, an exception's class and
 * arguments). Called with the GIL held (it makes Python objects), so the table needs no lock.
 */
#include <Python.h>
#include <stdint.h>

__attribute__((visibility("hidden"))) PyObject *numba_unpickle(const char *data, int n, const char *hashed);

#define SLOTS 4096 /* a power of two; the serialised constants of one module, with room */
static const char *keys[SLOTS];
static PyObject *values[SLOTS];

__attribute__((visibility("hidden"))) PyObject *
skyfix_unpickle(const char *data, int n, const char *hashed)
{
    size_t i = ((uintptr_t) data >> 3) & (SLOTS - 1);
    for (size_t probe = 0; probe < SLOTS; probe++, i = (i + 1) & (SLOTS - 1)) {
        if (keys[i] == data) {
            Py_INCREF(values[i]);
            return values[i];
        }
        if (keys[i] == NULL) {
            PyObject *obj = numba_unpickle(data, n, hashed);
            if (obj != NULL) {
                keys[i] = data;
                Py_INCREF(obj);
                values[i] = obj;
            }
            return obj;
        }
    }
    return numba_unpickle(data, n, hashed); /* the table is full: as numba does */
}

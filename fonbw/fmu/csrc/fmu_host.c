/* A minimal FMI 2.0 co-simulation host for the fonbw FMUs (tests, benchmark,
 * and an example of driving the native FMUs from C).
 *
 *   fmu_host run   LIB GUID RES N [MEMORY]  N steps of the eq.-19 input, one output per line
 *   fmu_host check LIB GUID RES LIB2 GUID2 RES2 N
 *                  two instances of LIB and one of LIB2 in one process; rollback by
 *                  get/set FMU state and by serialize/deserialize, replayed bit for bit;
 *                  a bad parameter refused with a log line; prints "ok" at the end
 *   fmu_host bench LIB GUID RES N           ns per doStep (setReal + doStep + getReal)
 *
 * LIB is the shared library, GUID the model description's guid, RES the
 * resources URI ("" for none). Value references: input 0, output 1 (the
 * native FMUs), kh 2, memory 50. Exit code 0 on success. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#ifdef _WIN32
#include <windows.h>
#define LOAD(p) (void *)LoadLibraryA(p)
#define SYM(h, s) (void *)GetProcAddress((HMODULE)(h), s)
#else
#include <dlfcn.h>
#define LOAD(p) dlopen(p, RTLD_NOW | RTLD_LOCAL)
#define SYM(h, s) dlsym(h, s)
#endif
#include "fmi2Functions.h"

typedef struct {
    fmi2InstantiateTYPE *instantiate; fmi2FreeInstanceTYPE *free_;
    fmi2SetupExperimentTYPE *setup; fmi2EnterInitializationModeTYPE *enter;
    fmi2ExitInitializationModeTYPE *exit_; fmi2SetRealTYPE *setReal; fmi2GetRealTYPE *getReal;
    fmi2SetStringTYPE *setString; fmi2DoStepTYPE *doStep; fmi2TerminateTYPE *terminate;
    fmi2GetFMUstateTYPE *getState; fmi2SetFMUstateTYPE *setState; fmi2FreeFMUstateTYPE *freeState;
    fmi2SerializedFMUstateSizeTYPE *serSize; fmi2SerializeFMUstateTYPE *serialize;
    fmi2DeSerializeFMUstateTYPE *deserialize;
} Api;

static int n_log = 0;
static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status st, fmi2String cat,
                   fmi2String msg, ...) {
    va_list ap;
    (void)env;
    n_log++;
    fprintf(stderr, "[%s status=%d %s] ", name, (int)st, cat);
    va_start(ap, msg);
    vfprintf(stderr, msg, ap);
    va_end(ap);
    fputc('\n', stderr);
}
static const fmi2CallbackFunctions CB = {logger, calloc, free, NULL, NULL};

#define FAIL(...) do { fprintf(stderr, __VA_ARGS__); fputc('\n', stderr); exit(1); } while (0)
#define OK(call) do { fmi2Status s_ = (call); if (s_ > fmi2Warning) FAIL("%s failed (%d) at line %d", #call, (int)s_, __LINE__); } while (0)

static void load(Api *a, const char *lib) {
    void *h = LOAD(lib);
    if (!h) FAIL("cannot load %s", lib);
#define GET(f, s) if (!(*(void **)&a->f = SYM(h, s))) FAIL("%s: missing %s", lib, s)
    GET(instantiate, "fmi2Instantiate"); GET(free_, "fmi2FreeInstance");
    GET(setup, "fmi2SetupExperiment"); GET(enter, "fmi2EnterInitializationMode");
    GET(exit_, "fmi2ExitInitializationMode"); GET(setReal, "fmi2SetReal"); GET(getReal, "fmi2GetReal");
    GET(setString, "fmi2SetString"); GET(doStep, "fmi2DoStep"); GET(terminate, "fmi2Terminate");
    GET(getState, "fmi2GetFMUstate"); GET(setState, "fmi2SetFMUstate"); GET(freeState, "fmi2FreeFMUstate");
    GET(serSize, "fmi2SerializedFMUstateSize"); GET(serialize, "fmi2SerializeFMUstate");
    GET(deserialize, "fmi2DeSerializeFMUstate");
#undef GET
}

static fmi2Component start(Api *a, const char *name, const char *guid, const char *res, const char *memory) {
    fmi2Component c = a->instantiate(name, fmi2CoSimulation, guid, res, &CB, fmi2False, fmi2False);
    if (!c) FAIL("instantiate %s failed", name);
    OK(a->setup(c, fmi2False, 0.0, 0.0, fmi2False, 0.0));
    OK(a->enter(c));
    if (memory && *memory) { fmi2ValueReference vr = 50; OK(a->setString(c, &vr, 1, &memory)); }
    OK(a->exit_(c));
    return c;
}

static double input(long k) {
    double t = (double)k * 1e-4;
    return 60.0 * exp(-0.13 * t) * (cos(3.0 * 3.141592653589793 * t * exp(-0.09 * t) - 3.15) + 1.0);
}

static double step(Api *a, fmi2Component c, long k, double scale) {
    fmi2ValueReference in = 0, out = 1;
    double u = scale * input(k), y;
    OK(a->setReal(c, &in, 1, &u));
    OK(a->doStep(c, (double)k * 1e-4, 1e-4, fmi2True));
    OK(a->getReal(c, &out, 1, &y));
    return y;
}

static double now(void) {
#ifdef _WIN32
    LARGE_INTEGER f, t;
    QueryPerformanceFrequency(&f);
    QueryPerformanceCounter(&t);
    return (double)t.QuadPart / (double)f.QuadPart;
#else
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
#endif
}

static int check(Api *a, Api *b, char **argv, long n) {
    fmi2Component c1 = start(a, "one", argv[3], argv[4], NULL), c2 = start(a, "two", argv[3], argv[4], "exact");
    fmi2Component d = start(b, "other", argv[6], argv[7], NULL), bad;
    fmi2FMUstate st = NULL, st2 = NULL;
    double *y = malloc(sizeof(double) * (size_t)n), kh = NAN, y2;
    fmi2ValueReference vr = 2;
    size_t sz;
    fmi2Byte *bytes;
    long k, half = n / 2;
    int logs;
    for (k = 0; k < half; k++) { step(a, c1, k, 1.0); step(a, c2, k, 1.0); step(b, d, k, 0.1); }
    OK(a->getState(c1, &st));
    OK(a->serSize(c1, st, &sz));
    bytes = malloc(sz);
    OK(a->serialize(c1, st, bytes, sz));
    for (k = half; k < n; k++) { y[k] = step(a, c1, k, 1.0); step(a, c2, k, 1.0); step(b, d, k, 0.1); }
    OK(a->setState(c1, st));  /* rollback */
    for (k = half; k < n; k++)
        if ((y2 = step(a, c1, k, 1.0)) != y[k]) FAIL("get/set state: step %ld gives %.17g, not %.17g", k, y2, y[k]);
    OK(a->deserialize(c2, bytes, sz, &st2));  /* into the other instance */
    OK(a->setState(c2, st2));
    for (k = half; k < n; k++)
        if ((y2 = step(a, c2, k, 1.0)) != y[k]) FAIL("serialized state: step %ld gives %.17g, not %.17g", k, y2, y[k]);
    OK(a->freeState(c1, &st)); OK(a->freeState(c2, &st2));
    free(bytes);
    bad = a->instantiate("bad", fmi2CoSimulation, argv[3], argv[4], &CB, fmi2False, fmi2False);
    OK(a->setup(bad, fmi2False, 0.0, 0.0, fmi2False, 0.0));
    OK(a->enter(bad));
    OK(a->setReal(bad, &vr, 1, &kh));
    logs = n_log;
    if (a->exit_(bad) != fmi2Error || n_log == logs) FAIL("a non-finite kh was not refused with a log line");
    a->free_(bad);
    OK(a->terminate(c1)); OK(a->terminate(c2)); OK(b->terminate(d));
    a->free_(c1); a->free_(c2); b->free_(d);
    free(y);
    printf("ok\n");
    return 0;
}

int main(int argc, char **argv) {
    Api a, b;
    long n, k;
    if (argc < 6) FAIL("usage: see the head of fmu_host.c");
    load(&a, argv[2]);
    if (strcmp(argv[1], "run") == 0) {
        fmi2Component c = start(&a, "run", argv[3], argv[4], argc > 6 ? argv[6] : NULL);
        n = atol(argv[5]);
        for (k = 0; k < n; k++) printf("%.17g\n", step(&a, c, k, 1.0));
        OK(a.terminate(c));
        a.free_(c);
        return 0;
    }
    if (strcmp(argv[1], "bench") == 0) {
        fmi2Component c = start(&a, "bench", argv[3], argv[4], NULL);
        double t0, t1, s = 0.0;
        n = atol(argv[5]);
        for (k = 0; k < 1000; k++) s += step(&a, c, k, 1.0);  /* warm-up */
        t0 = now();
        for (k = 1000; k < n + 1000; k++) s += step(&a, c, k, 1.0);
        t1 = now();
        printf("%.6g ns/step (checksum %.6g)\n", 1e9 * (t1 - t0) / (double)n, s);
        OK(a.terminate(c));
        a.free_(c);
        return 0;
    }
    if (strcmp(argv[1], "check") == 0 && argc >= 9) {
        load(&b, argv[5]);
        return check(&a, &b, argv, atol(argv[8]));
    }
    FAIL("unknown mode %s", argv[1]);
}

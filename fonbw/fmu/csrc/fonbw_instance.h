/* One instance of a fonbw native FMU, shared by the FMI 2.0 interface
 * (fonbw_fmi2.c: life cycle, variable access, stepping, FMU state) and the
 * per-model parts (fonbw_model.c: which variables a kind has, its start
 * values, building the model from the parameters, the internal steps, the
 * model's own state).
 *
 * config.h (written by the builder into each FMU's sources/) selects the
 * model and holds the build-time start values:
 *   MODEL_KIND 1  FonbwHysteresisNative   u [V]     -> y [um]
 *   MODEL_KIND 2  FonbwCompensatorNative  y_ref [um] -> u [V], status
 *   MODEL_KIND 3  FonbwLinearPlantNative  input -> output (state space)
 *   MODEL_KIND 4  FonbwPIDNative          r, y [um], u_ff [V] -> u [V]
 *   MODEL_KIND 5  FonbwSignalNative       (no input) -> y, a table of samples
 *                                          from the text file named by `file`
 * With PASS_THROUGH defined, the FMU keeps the variables, parameters and
 * checks of its kind but its step is output = first input (a baseline that
 * shows what a master spends around the model). */
#ifndef FONBW_INSTANCE_H
#define FONBW_INSTANCE_H

#include <stddef.h>

#include "config.h"
#include "fmi2Functions.h"
#include "fonbw_numerics.h"

#define KIND_HYST 1
#define KIND_COMP 2
#define KIND_PLANT 3
#define KIND_PID 4
#define KIND_SIGNAL 5
/* the kinds built on a FONBW model (its parameters, start and memory) */
#define HAS_FONBW (MODEL_KIND == KIND_HYST || MODEL_KIND == KIND_COMP)
#ifndef PASS_THROUGH
#define PASS_THROUGH 0
#endif

/* value references (Real, Integer and String share one numbering) */
enum { VR_IN = 0, VR_OUT = 1, VR_KH = 2, VR_RHO = 3, VR_SIGMA = 4, VR_N = 5, VR_LAM1 = 6,
       VR_LAM2 = 7, VR_DT = 8, VR_UMIN = 9, VR_UMAX = 10, VR_Y = 11, VR_UFF = 12, VR_KP = 13,
       VR_KI = 14, VR_KD = 15, VR_TF = 16, VR_TT = 17, VR_KU = 20,
       VR_K = 40, VR_M = 41, VR_L = 42, VR_STATUS = 43, VR_REST_LO = 44,
       VR_REST_HI = 45, VR_REST_T = 46, VR_MEMORY = 50, VR_INTEGRATOR = 51,
       VR_ANTI_WINDUP = 52, VR_FILE = 60, NVR = 61 };

typedef enum { ST_INSTANTIATED = 1, ST_INIT = 2, ST_STEP = 4, ST_TERMINATED = 8, ST_ERROR = 16 } Phase;
#define ANY (ST_INSTANTIATED | ST_INIT | ST_STEP | ST_TERMINATED | ST_ERROR)

typedef struct {
    char *name;
    fmi2CallbackFunctions cb;
    int logging;
    Phase phase;
    double time;
    double r[NVR];          /* Real variables by value reference */
    int i[NVR];             /* Integer variables by value reference */
    int engine;             /* the String parameter memory */
    int built;              /* the model below exists */
    double built_from[NVR]; /* parameters it was built from */
    int built_from_i[NVR];
    int built_engine;
    Fonbw hyst;
    double hyst_y0;         /* hysteresis: output at the end of its rest cycle */
    Compensator comp;
    Plant plant;
    Pid pid;
    int bad_before;         /* compensator: in a saturation episode */
    char *file;             /* signal: the String parameter file (NULL: empty) */
    char *loaded_from;      /* signal: the file the table was read from (NULL: none) */
    double *table;          /* signal: the samples */
    size_t n_table, k_table; /* signal: samples; internal steps done */
} Instance;

/* a log line through the host's logger (fmi2OK lines only with debug logging on) */
void fonbw_log(Instance *c, fmi2Status st, const char *cat, const char *fmt, ...);

/* which variables this kind has */
int inst_is_input(int vr);
int inst_is_param(int vr);
int inst_is_real(int vr);
int inst_is_int(int vr);
/* the names a String parameter takes (NULL: not an enumerated String), and where its index is kept */
const char **inst_string_names(Instance *c, int vr, int *count, int **slot);
/* where a free-text String parameter is kept (NULL: not one) */
char **inst_text(Instance *c, int vr);

void inst_set_defaults(Instance *c);
void inst_free_model(Instance *c);
/* what the instance holds apart from the model (strings, tables), at fmi2Reset and fmi2FreeInstance */
void inst_release(Instance *c);
/* when initialization starts: 0, or -1 with an fmi2Error log line */
int inst_enter_init(Instance *c);
/* build the model from the parameters: 0, or -1 with an fmi2Error log line */
int inst_build_model(Instance *c);
int inst_params_changed(const Instance *c);
double inst_output(const Instance *c);
/* k internal steps of dt */
void inst_steps(Instance *c, long k);

/* signal (fonbw_table.c): read the table named by c->file (0, or -1 with an
 * fmi2Error log line, no table kept), and let it go */
int table_load(Instance *c);
void table_drop(Instance *c);

/* the model's own state as doubles: size, write, read (0, or -1 if it does not fit) */
size_t inst_model_size(const Instance *c);
void inst_model_write(const Instance *c, double *d);
int inst_model_read(Instance *c, const double *d, size_t nm);

#endif

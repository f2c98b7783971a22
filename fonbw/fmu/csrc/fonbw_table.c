/* The table of samples of FonbwSignalNative (MODEL_KIND 5, see
 * fonbw_instance.h): a text file, one number per line, written with 17
 * significant digits so that a correctly rounding strtod (glibc, macOS, the
 * UCRT) reads every sample back bit for bit. Read when initialization starts
 * and again when it ends if `file` changed in between (fonbw_model.c). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fonbw_instance.h"

void table_drop(Instance *c) {
    free(c->table); c->table = NULL; c->n_table = 0;
    free(c->loaded_from); c->loaded_from = NULL;
}

int table_load(Instance *c) {
    FILE *f;
    char line[256], *end;
    size_t cap = 0, row = 0;
    table_drop(c);
    if (!c->file || !*c->file) {
        fonbw_log(c, fmi2Error, "logStatusError", "invalid parameters: file is empty (no table of samples)");
        return -1;
    }
    if (!(f = fopen(c->file, "r"))) {
        fonbw_log(c, fmi2Error, "logStatusError", "invalid parameters: cannot open file '%s'", c->file);
        return -1;
    }
    while (fgets(line, sizeof line, f)) {
        double v;
        const char *p = line;
        row++;
        if (!strchr(line, '\n') && !feof(f)) {
            fonbw_log(c, fmi2Error, "logStatusError", "invalid parameters: line %lu of '%s' is longer than "
                      "%d characters", (unsigned long)row, c->file, (int)sizeof line - 2);
            fclose(f); table_drop(c);
            return -1;
        }
        while (*p == ' ' || *p == '\t' || *p == '\r' || *p == '\n') p++;
        if (!*p) continue;  /* a blank line, LF or CRLF, with or without spaces */
        v = strtod(p, &end);
        if (end == p) end = line;  /* nothing converted: not a number */
        else while (*end == ' ' || *end == '\t' || *end == '\r' || *end == '\n') end++;
        if (end == line || *end || !isfinite(v)) {
            fonbw_log(c, fmi2Error, "logStatusError", "invalid parameters: line %lu of '%s' is not a "
                      "finite number", (unsigned long)row, c->file);
            fclose(f); table_drop(c);
            return -1;
        }
        if (c->n_table == cap) {
            double *t = realloc(c->table, sizeof(double) * (cap = cap ? 2 * cap : 1024));
            if (!t) { fclose(f); table_drop(c); fonbw_log(c, fmi2Error, "logStatusError", "out of memory"); return -1; }
            c->table = t;
        }
        c->table[c->n_table++] = v;
    }
    fclose(f);
    if (!c->n_table) {
        fonbw_log(c, fmi2Error, "logStatusError", "invalid parameters: '%s' holds no sample", c->file);
        return -1;
    }
    if (!(c->loaded_from = malloc(strlen(c->file) + 1))) {
        table_drop(c);
        fonbw_log(c, fmi2Error, "logStatusError", "out of memory");
        return -1;
    }
    strcpy(c->loaded_from, c->file);
    return 0;
}

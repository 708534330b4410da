/*
 * cip_engine.c - a physics engine for cipval's coupled inverted pendula (CIP), in plain C.
 *
 * It speaks cipval's chunk exchange protocol (cip/engines/process.py) over
 * stdin/stdout: one JSON header line in, one JSON answer line out, then binary
 * request/response frames (little-endian int64 and float64) until a request with
 * n = 0 ends the session; it then reads the next header (another session) or the
 * end of its stdin, where it exits with status 0.
 *
 * The model is built from the header's "parameters" only (never the MJB binary):
 * per balancer i a cart of mass M on a slide along +x (coordinate x, at world
 * x0 + x), a massless pole of length L on a hinge about +y (angle th, th > 0 tilts
 * the tip to +x), a bob of mass m and central inertia I (about the hinge axis) at
 * the tip (x0 + x + L sin th, L cos th).  Lagrange's equations per balancer:
 *
 *   [ M+m         m L cos th ] [ x''  ]   [ Q_x  + m L sin th th'^2      ]
 *   [ m L cos th  m L^2 + I  ] [ th'' ] = [ Q_th                         ]
 *
 * with the generalised forces of gravity (the vector g: Q_x += (M+m) g_x,
 * Q_th += m L (g_x cos th - g_z sin th)), tip damping (F_t = -c_tip v_tip,x,
 * v_tip,x = x' + L cos th th': Q_x += F_t, Q_th += F_t L cos th), cart damping
 * (Q_x += -c_cart x') and the motor (Q_x += gear u).  The coupled model joins the
 * two tips by a rigid massless rod of length l: g(q) = |p_1 - p_2| - l = 0.
 *
 * Stepping: semi-implicit (symplectic) Euler, v_free = v + dt M(q)^-1 (Q - bias),
 * then for the rod the scalar impulse lambda with J v+ = -g(q)/dt (a velocity
 * projection with position correction; J = dg/dq), v+ = v_free + M^-1 J^T lambda,
 * and q+ = q + dt v+.  Time advances by dt; the rest of the state passes through.
 *
 * Faults (for cipval to catch): --fault length (pendulum length 1.005 L in the
 * dynamics), --fault delay (each control applied one step late, 0 on a session's
 * first step).
 *
 * Only libc and libm.  Build: see the Makefile (cc -O2 -std=c11 ... -lm).
 */

#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define ENGINE_NAME "c-engine"
#define MAX_DEPTH 64
#define MAX_CONTROLLERS 16

/* ------------------------------------------------------------------ small helpers */

static void die(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "cip_engine: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
    exit(2);
}

static void *xrealloc(void *p, size_t n)
{
    void *q = realloc(p, n ? n : 1);
    if (!q)
        die("out of memory (%zu bytes)", n);
    return q;
}

/* ------------------------------------------------------------------ a tiny JSON reader */

typedef enum { J_NULL, J_BOOL, J_NUM, J_STR, J_ARR, J_OBJ } jtype;

typedef struct jval {
    jtype type;
    double num;          /* J_NUM; J_BOOL: 0 or 1 */
    char *str;           /* J_STR: decoded UTF-8, NUL-terminated */
    struct jval *items;  /* J_ARR, J_OBJ: the values */
    char **keys;         /* J_OBJ: the keys */
    size_t n, cap;
} jval;

typedef struct {
    const char *s;
    size_t i, n;
    int depth;
    char err[160];
} jparser;

static void jfree(jval *v)
{
    if (v->type == J_STR)
        free(v->str);
    if (v->type == J_ARR || v->type == J_OBJ) {
        for (size_t k = 0; k < v->n; k++) {
            jfree(&v->items[k]);
            if (v->keys)
                free(v->keys[k]);
        }
        free(v->items);
        free(v->keys);
    }
    memset(v, 0, sizeof *v);
}

static int jfail(jparser *p, const char *what)
{
    if (!p->err[0])
        snprintf(p->err, sizeof p->err, "JSON: %s at byte %zu", what, p->i);
    return 0;
}

static void jskip_ws(jparser *p)
{
    while (p->i < p->n && (p->s[p->i] == ' ' || p->s[p->i] == '\t' || p->s[p->i] == '\n' ||
                           p->s[p->i] == '\r'))
        p->i++;
}

static int jliteral(jparser *p, const char *word)
{
    size_t k = strlen(word);
    if (p->n - p->i >= k && memcmp(p->s + p->i, word, k) == 0) {
        p->i += k;
        return 1;
    }
    return 0;
}

static int jhex4(jparser *p, unsigned *out)
{
    unsigned v = 0;
    if (p->n - p->i < 4)
        return jfail(p, "short \\u escape");
    for (int k = 0; k < 4; k++) {
        char c = p->s[p->i++];
        v <<= 4;
        if (c >= '0' && c <= '9')
            v |= (unsigned)(c - '0');
        else if (c >= 'a' && c <= 'f')
            v |= (unsigned)(c - 'a' + 10);
        else if (c >= 'A' && c <= 'F')
            v |= (unsigned)(c - 'A' + 10);
        else
            return jfail(p, "bad \\u escape");
    }
    *out = v;
    return 1;
}

/* a string at p->i (the opening quote), decoded into a fresh buffer */
static int jstring(jparser *p, char **out)
{
    size_t cap = 16, len = 0;
    char *buf = xrealloc(NULL, cap);
    p->i++; /* the quote */
    for (;;) {
        if (p->i >= p->n) {
            free(buf);
            return jfail(p, "unterminated string");
        }
        unsigned char c = (unsigned char)p->s[p->i++];
        unsigned cp;
        if (c == '"')
            break;
        if (c < 0x20) {
            free(buf);
            return jfail(p, "control character in string");
        }
        if (len + 5 > cap) {
            cap *= 2;
            buf = xrealloc(buf, cap);
        }
        if (c != '\\') {
            buf[len++] = (char)c;
            continue;
        }
        if (p->i >= p->n) {
            free(buf);
            return jfail(p, "unterminated escape");
        }
        c = (unsigned char)p->s[p->i++];
        switch (c) {
        case '"': buf[len++] = '"'; continue;
        case '\\': buf[len++] = '\\'; continue;
        case '/': buf[len++] = '/'; continue;
        case 'b': buf[len++] = '\b'; continue;
        case 'f': buf[len++] = '\f'; continue;
        case 'n': buf[len++] = '\n'; continue;
        case 'r': buf[len++] = '\r'; continue;
        case 't': buf[len++] = '\t'; continue;
        case 'u': break;
        default: free(buf); return jfail(p, "bad escape");
        }
        if (!jhex4(p, &cp)) {
            free(buf);
            return 0;
        }
        if (cp >= 0xD800 && cp <= 0xDBFF) { /* a surrogate pair */
            unsigned lo;
            if (!(jliteral(p, "\\u") && jhex4(p, &lo) && lo >= 0xDC00 && lo <= 0xDFFF)) {
                free(buf);
                return jfail(p, "bad surrogate pair");
            }
            cp = 0x10000 + ((cp - 0xD800) << 10) + (lo - 0xDC00);
        }
        if (cp < 0x80) {
            buf[len++] = (char)cp;
        } else if (cp < 0x800) {
            buf[len++] = (char)(0xC0 | (cp >> 6));
            buf[len++] = (char)(0x80 | (cp & 0x3F));
        } else if (cp < 0x10000) {
            buf[len++] = (char)(0xE0 | (cp >> 12));
            buf[len++] = (char)(0x80 | ((cp >> 6) & 0x3F));
            buf[len++] = (char)(0x80 | (cp & 0x3F));
        } else {
            buf[len++] = (char)(0xF0 | (cp >> 18));
            buf[len++] = (char)(0x80 | ((cp >> 12) & 0x3F));
            buf[len++] = (char)(0x80 | ((cp >> 6) & 0x3F));
            buf[len++] = (char)(0x80 | (cp & 0x3F));
        }
    }
    buf[len] = '\0';
    *out = buf;
    return 1;
}

/* a number (JSON's grammar; also NaN, Infinity, -Infinity as Python's json writes them) */
static int jnumber(jparser *p, double *out)
{
    size_t start = p->i, k = p->i;
    char tmp[64];
    if (jliteral(p, "NaN")) {
        *out = NAN;
        return 1;
    }
    if (jliteral(p, "Infinity")) {
        *out = INFINITY;
        return 1;
    }
    if (jliteral(p, "-Infinity")) {
        *out = -INFINITY;
        return 1;
    }
    if (k < p->n && p->s[k] == '-')
        k++;
    if (k >= p->n || p->s[k] < '0' || p->s[k] > '9')
        return jfail(p, "bad value");
    while (k < p->n && p->s[k] >= '0' && p->s[k] <= '9')
        k++;
    if (k < p->n && p->s[k] == '.') {
        k++;
        if (k >= p->n || p->s[k] < '0' || p->s[k] > '9')
            return jfail(p, "bad number");
        while (k < p->n && p->s[k] >= '0' && p->s[k] <= '9')
            k++;
    }
    if (k < p->n && (p->s[k] == 'e' || p->s[k] == 'E')) {
        k++;
        if (k < p->n && (p->s[k] == '+' || p->s[k] == '-'))
            k++;
        if (k >= p->n || p->s[k] < '0' || p->s[k] > '9')
            return jfail(p, "bad exponent");
        while (k < p->n && p->s[k] >= '0' && p->s[k] <= '9')
            k++;
    }
    if (k - start >= sizeof tmp)
        return jfail(p, "number too long");
    memcpy(tmp, p->s + start, k - start);
    tmp[k - start] = '\0';
    *out = strtod(tmp, NULL); /* the "C" locale: this program never calls setlocale */
    p->i = k;
    return 1;
}

static int jvalue(jparser *p, jval *v);

static void jappend(jval *parent, jval *child, char *key)
{
    if (parent->n == parent->cap) {
        parent->cap = parent->cap ? 2 * parent->cap : 4;
        parent->items = xrealloc(parent->items, parent->cap * sizeof *parent->items);
        if (parent->type == J_OBJ)
            parent->keys = xrealloc(parent->keys, parent->cap * sizeof *parent->keys);
    }
    parent->items[parent->n] = *child;
    if (parent->type == J_OBJ)
        parent->keys[parent->n] = key;
    parent->n++;
}

static int jcontainer(jparser *p, jval *v, int obj)
{
    char close = obj ? '}' : ']';
    v->type = obj ? J_OBJ : J_ARR;
    p->i++; /* the opening bracket */
    if (++p->depth > MAX_DEPTH)
        return jfail(p, "nested too deeply");
    jskip_ws(p);
    if (p->i < p->n && p->s[p->i] == close) {
        p->i++;
        p->depth--;
        return 1;
    }
    for (;;) {
        char *key = NULL;
        jval child;
        memset(&child, 0, sizeof child);
        jskip_ws(p);
        if (obj) {
            if (p->i >= p->n || p->s[p->i] != '"')
                return jfail(p, "expected a key");
            if (!jstring(p, &key))
                return 0;
            jskip_ws(p);
            if (p->i >= p->n || p->s[p->i] != ':') {
                free(key);
                return jfail(p, "expected ':'");
            }
            p->i++;
        }
        if (!jvalue(p, &child)) {
            free(key);
            jfree(&child);
            return 0;
        }
        jappend(v, &child, key);
        jskip_ws(p);
        if (p->i < p->n && p->s[p->i] == ',') {
            p->i++;
            continue;
        }
        if (p->i < p->n && p->s[p->i] == close) {
            p->i++;
            p->depth--;
            return 1;
        }
        return jfail(p, obj ? "expected ',' or '}'" : "expected ',' or ']'");
    }
}

static int jvalue(jparser *p, jval *v)
{
    memset(v, 0, sizeof *v);
    jskip_ws(p);
    if (p->i >= p->n)
        return jfail(p, "unexpected end");
    switch (p->s[p->i]) {
    case '{': return jcontainer(p, v, 1);
    case '[': return jcontainer(p, v, 0);
    case '"': v->type = J_STR; return jstring(p, &v->str);
    case 't':
        if (!jliteral(p, "true"))
            return jfail(p, "bad literal");
        v->type = J_BOOL;
        v->num = 1;
        return 1;
    case 'f':
        if (!jliteral(p, "false"))
            return jfail(p, "bad literal");
        v->type = J_BOOL;
        return 1;
    case 'n':
        if (!jliteral(p, "null"))
            return jfail(p, "bad literal");
        v->type = J_NULL;
        return 1;
    default: v->type = J_NUM; return jnumber(p, &v->num);
    }
}

/* parse a whole document; 1 on success, else 0 with the reason in err */
static int jparse(const char *s, size_t n, jval *out, char *err, size_t errlen)
{
    jparser p = {s, 0, n, 0, {0}};
    int ok = jvalue(&p, out);
    if (ok) {
        jskip_ws(&p);
        if (p.i != p.n)
            ok = jfail(&p, "trailing characters");
    }
    if (!ok) {
        jfree(out);
        snprintf(err, errlen, "%s", p.err);
    }
    return ok;
}

static const jval *jget(const jval *obj, const char *key)
{
    if (!obj || obj->type != J_OBJ)
        return NULL;
    for (size_t k = 0; k < obj->n; k++)
        if (strcmp(obj->keys[k], key) == 0)
            return &obj->items[k];
    return NULL;
}

/* ------------------------------------------------------------------ the model */

typedef struct {
    int nc;           /* balancers (n_controllers) */
    int R, S, U, nq;  /* realisations, state size, controls, qpos size */
    double dt, grav[3];
    double M[MAX_CONTROLLERS], x0[MAX_CONTROLLERS], m[MAX_CONTROLLERS], L[MAX_CONTROLLERS];
    double I[MAX_CONTROLLERS], ctip[MAX_CONTROLLERS], ccart[MAX_CONTROLLERS];
    double gear[MAX_CONTROLLERS];
    int motor[MAX_CONTROLLERS], qx[MAX_CONTROLLERS], qth[MAX_CONTROLLERS];
    int vx[MAX_CONTROLLERS], vth[MAX_CONTROLLERS];
    int has_rod;
    double rod;
} cip_model;

typedef enum { FAULT_NONE, FAULT_LENGTH, FAULT_DELAY } fault_t;

static int is_int(double x) { return isfinite(x) && x == floor(x) && fabs(x) < 1e9; }

/* a number field of obj; 0 with a message when absent or not a number */
static int get_num(const jval *obj, const char *key, double *out, char *err, size_t errlen)
{
    const jval *v = jget(obj, key);
    if (!v || v->type != J_NUM) {
        snprintf(err, errlen, "header field %s is missing or not a number", key);
        return 0;
    }
    *out = v->num;
    return 1;
}

static int get_int(const jval *obj, const char *key, int lo, int hi, int *out, char *err,
                   size_t errlen)
{
    double x;
    if (!get_num(obj, key, &x, err, errlen))
        return 0;
    if (!is_int(x) || x < lo || x > hi) {
        snprintf(err, errlen, "header field %s = %g is not an integer in [%d, %d]", key, x, lo,
                 hi);
        return 0;
    }
    *out = (int)x;
    return 1;
}

/* parameters[key]: an array of nc numbers */
static int get_row(const jval *par, const char *key, int nc, double *out, char *err,
                   size_t errlen)
{
    const jval *v = jget(par, key);
    if (!v || v->type != J_ARR || (int)v->n != nc) {
        snprintf(err, errlen, "parameters.%s must be an array of %d numbers", key, nc);
        return 0;
    }
    for (int i = 0; i < nc; i++) {
        if (v->items[i].type != J_NUM || !isfinite(v->items[i].num)) {
            snprintf(err, errlen, "parameters.%s[%d] is not a finite number", key, i);
            return 0;
        }
        out[i] = v->items[i].num;
    }
    return 1;
}

static int get_index_row(const jval *par, const char *key, int nc, int hi, int *out, char *err,
                         size_t errlen)
{
    double tmp[MAX_CONTROLLERS];
    if (!get_row(par, key, nc, tmp, err, errlen))
        return 0;
    for (int i = 0; i < nc; i++) {
        if (!is_int(tmp[i]) || tmp[i] < 0 || tmp[i] >= hi) {
            snprintf(err, errlen, "parameters.%s[%d] = %g is not an index below %d", key, i,
                     tmp[i], hi);
            return 0;
        }
        out[i] = (int)tmp[i];
    }
    return 1;
}

/* nq, the size of qpos: the header's "joints" map gives each joint's state indices
 * (qpos: 1 + qpos address, qvel: 1 + nq + dof address), so the joint of qpos_x[0]
 * gives nq; a header without it: nq = nv = 2 nc (a slide and a hinge per balancer) */
static int find_nq(const jval *hdr, int qx0, int vx0, int nc, int *nq, char *err, size_t errlen)
{
    const jval *joints = jget(hdr, "joints");
    if (joints && joints->type == J_OBJ) {
        for (size_t k = 0; k < joints->n; k++) {
            const jval *qp = jget(&joints->items[k], "qpos");
            const jval *qv = jget(&joints->items[k], "qvel");
            if (qp && qv && qp->type == J_NUM && qv->type == J_NUM && qp->num == 1.0 + qx0) {
                double x = qv->num - 1.0 - vx0;
                if (!is_int(x) || x < 0) {
                    snprintf(err, errlen, "joints: inconsistent qpos/qvel indices");
                    return 0;
                }
                *nq = (int)x;
                return 1;
            }
        }
    }
    *nq = 2 * nc;
    return 1;
}

/* the model from a header (cipval-chunk version 1); 0 with a message when refused */
static int build_model(const jval *hdr, fault_t fault, cip_model *md, char *err, size_t errlen)
{
    const jval *par = jget(hdr, "parameters"), *rod;
    const jval *grav;
    double nc_d;
    memset(md, 0, sizeof *md);
    if (!get_int(hdr, "n_realizations", 1, 100000000, &md->R, err, errlen) ||
        !get_int(hdr, "nstate", 1, 100000000, &md->S, err, errlen) ||
        !get_int(hdr, "nu", 0, 100000000, &md->U, err, errlen) ||
        !get_num(hdr, "timestep", &md->dt, err, errlen))
        return 0;
    if (!(md->dt > 0) || !isfinite(md->dt)) {
        snprintf(err, errlen, "timestep %g must be positive", md->dt);
        return 0;
    }
    if (!par || par->type != J_OBJ) {
        snprintf(err, errlen, "the header has no parameters object");
        return 0;
    }
    if (!get_num(par, "n_controllers", &nc_d, err, errlen))
        return 0;
    if (!is_int(nc_d) || nc_d < 1 || nc_d > MAX_CONTROLLERS) {
        snprintf(err, errlen, "n_controllers = %g is not an integer in [1, %d]", nc_d,
                 MAX_CONTROLLERS);
        return 0;
    }
    md->nc = (int)nc_d;
    grav = jget(par, "gravity");
    if (!grav || grav->type != J_ARR || grav->n != 3) {
        snprintf(err, errlen, "parameters.gravity must be an array of 3 numbers");
        return 0;
    }
    for (int k = 0; k < 3; k++) {
        if (grav->items[k].type != J_NUM || !isfinite(grav->items[k].num)) {
            snprintf(err, errlen, "parameters.gravity[%d] is not a finite number", k);
            return 0;
        }
        md->grav[k] = grav->items[k].num;
    }
    int nc = md->nc;
    if (!get_row(par, "cart_mass", nc, md->M, err, errlen) ||
        !get_row(par, "cart_x0", nc, md->x0, err, errlen) ||
        !get_row(par, "bob_mass", nc, md->m, err, errlen) ||
        !get_row(par, "pendulum_length", nc, md->L, err, errlen) ||
        !get_row(par, "tip_damping", nc, md->ctip, err, errlen) ||
        !get_row(par, "cart_damping", nc, md->ccart, err, errlen) ||
        !get_row(par, "motor_gear", nc, md->gear, err, errlen))
        return 0;
    /* bob_inertia: per balancer the 3 principal central moments; the hinge is about y */
    const jval *inertia = jget(par, "bob_inertia");
    if (!inertia || inertia->type != J_ARR || (int)inertia->n != nc) {
        snprintf(err, errlen, "parameters.bob_inertia must be an array of %d triples", nc);
        return 0;
    }
    for (int i = 0; i < nc; i++) {
        const jval *t = &inertia->items[i];
        if (t->type != J_ARR || t->n != 3 || t->items[1].type != J_NUM ||
            !isfinite(t->items[1].num)) {
            snprintf(err, errlen, "parameters.bob_inertia[%d] must be 3 numbers", i);
            return 0;
        }
        md->I[i] = t->items[1].num;
    }
    if (!get_index_row(par, "motor_id", nc, md->U, md->motor, err, errlen) ||
        !get_index_row(par, "qpos_x", nc, 1 << 20, md->qx, err, errlen) ||
        !get_index_row(par, "qpos_theta", nc, 1 << 20, md->qth, err, errlen) ||
        !get_index_row(par, "dof_x", nc, 1 << 20, md->vx, err, errlen) ||
        !get_index_row(par, "dof_theta", nc, 1 << 20, md->vth, err, errlen))
        return 0;
    if (!find_nq(hdr, md->qx[0], md->vx[0], nc, &md->nq, err, errlen))
        return 0;
    for (int i = 0; i < nc; i++) {
        int hi = md->qx[i] > md->qth[i] ? md->qx[i] : md->qth[i];
        int hv = md->vx[i] > md->vth[i] ? md->vx[i] : md->vth[i];
        if (hi >= md->nq || 1 + md->nq + hv >= md->S) {
            snprintf(err, errlen, "balancer %d's indices fall outside the state (nstate %d)",
                     i + 1, md->S);
            return 0;
        }
        if (!(md->M[i] + md->m[i] > 0) || !(md->L[i] > 0) || md->m[i] < 0 || md->I[i] < 0) {
            snprintf(err, errlen, "balancer %d: masses and length must be positive", i + 1);
            return 0;
        }
        if (fault == FAULT_LENGTH)
            md->L[i] *= 1.005;
    }
    rod = jget(par, "rod_length");
    if (rod && rod->type == J_NUM) {
        if (nc != 2 || !(rod->num > 0) || !isfinite(rod->num)) {
            snprintf(err, errlen, "a rod (length %g) needs exactly 2 balancers, got %d",
                     rod->num, nc);
            return 0;
        }
        md->has_rod = 1;
        md->rod = rod->num;
    } else if (rod && rod->type != J_NULL) {
        snprintf(err, errlen, "parameters.rod_length must be a number or null");
        return 0;
    }
    return 1;
}

/* One semi-implicit Euler step of one realisation: state s (S values) under the
 * controls u (U values) to out (S values). */
static void step(const cip_model *md, const double *s, const double *u, double *out)
{
    const int nq = md->nq;
    const double dt = md->dt, gx = md->grav[0], gz = md->grav[2];
    double vx[MAX_CONTROLLERS], vth[MAX_CONTROLLERS];
    double inv11[MAX_CONTROLLERS], inv12[MAX_CONTROLLERS], inv22[MAX_CONTROLLERS];
    double c[MAX_CONTROLLERS], sn[MAX_CONTROLLERS];

    memmove(out, s, (size_t)md->S * sizeof *out); /* what this engine does not model */
    for (int i = 0; i < md->nc; i++) {
        const double M = md->M[i], m = md->m[i], L = md->L[i];
        const double th = s[1 + md->qth[i]];
        const double xd = s[1 + nq + md->vx[i]], thd = s[1 + nq + md->vth[i]];
        c[i] = cos(th);
        sn[i] = sin(th);
        /* mass matrix and its inverse */
        const double a11 = M + m, a12 = m * L * c[i], a22 = m * L * L + md->I[i];
        const double det = a11 * a22 - a12 * a12;
        inv11[i] = a22 / det;
        inv12[i] = -a12 / det;
        inv22[i] = a11 / det;
        /* generalised forces less the bias (Coriolis/centrifugal) term */
        const double ft = -md->ctip[i] * (xd + L * c[i] * thd);
        const double qx = md->gear[i] * u[md->motor[i]] - md->ccart[i] * xd + ft +
                          m * L * sn[i] * thd * thd + (M + m) * gx;
        const double qth = ft * L * c[i] + m * L * (gx * c[i] - gz * sn[i]);
        vx[i] = xd + dt * (inv11[i] * qx + inv12[i] * qth);
        vth[i] = thd + dt * (inv12[i] * qx + inv22[i] * qth);
    }
    if (md->has_rod) {
        /* g(q) = |p_1 - p_2| - l, the tips p_i = (x0 + x + L sin th, L cos th) */
        double px[2], pz[2], jx[2], jth[2], wx[2], wth[2];
        for (int i = 0; i < 2; i++) {
            px[i] = md->x0[i] + s[1 + md->qx[i]] + md->L[i] * sn[i];
            pz[i] = md->L[i] * c[i];
        }
        const double dx = px[0] - px[1], dz = pz[0] - pz[1];
        const double dist = sqrt(dx * dx + dz * dz);
        if (dist > 0) {
            const double nx = dx / dist, nz = dz / dist;
            double k = 0, jv = 0;
            for (int i = 0; i < 2; i++) {
                const double sign = i == 0 ? 1.0 : -1.0;
                /* dp_i/dx_i = (1, 0), dp_i/dth_i = (L cos th, -L sin th) */
                jx[i] = sign * nx;
                jth[i] = sign * (nx * md->L[i] * c[i] - nz * md->L[i] * sn[i]);
                wx[i] = inv11[i] * jx[i] + inv12[i] * jth[i];  /* M^-1 J^T */
                wth[i] = inv12[i] * jx[i] + inv22[i] * jth[i];
                k += jx[i] * wx[i] + jth[i] * wth[i];
                jv += jx[i] * vx[i] + jth[i] * vth[i];
            }
            if (k > 0) {
                const double lambda = (-(dist - md->rod) / dt - jv) / k;
                for (int i = 0; i < 2; i++) {
                    vx[i] += lambda * wx[i];
                    vth[i] += lambda * wth[i];
                }
            }
        }
    }
    for (int i = 0; i < md->nc; i++) {
        out[1 + nq + md->vx[i]] = vx[i];
        out[1 + nq + md->vth[i]] = vth[i];
        out[1 + md->qx[i]] = s[1 + md->qx[i]] + dt * vx[i];
        out[1 + md->qth[i]] = s[1 + md->qth[i]] + dt * vth[i];
    }
    out[0] = s[0] + dt;
}

/* ------------------------------------------------------------------ the wire */

static int little_endian(void)
{
    const uint16_t one = 1;
    return *(const unsigned char *)&one == 1;
}

static void swap8(void *p, size_t count)
{
    unsigned char *b = p;
    for (size_t k = 0; k < count; k++, b += 8)
        for (int j = 0; j < 4; j++) {
            unsigned char t = b[j];
            b[j] = b[7 - j];
            b[7 - j] = t;
        }
}

/* read count 8-byte little-endian values; 0 at the end of the input */
static int read8(void *buf, size_t count)
{
    if (count && fread(buf, 8, count, stdin) != count)
        return 0;
    if (!little_endian())
        swap8(buf, count);
    return 1;
}

static void write8(void *buf, size_t count)
{
    if (!little_endian())
        swap8(buf, count);
    if (count && fwrite(buf, 8, count, stdout) != count)
        die("cannot write to stdout");
    if (!little_endian())
        swap8(buf, count);
}

/* one line of stdin without its newline (NUL-terminated in *buf); -1 at the end */
static long read_line(char **buf, size_t *cap)
{
    size_t len = 0;
    int ch;
    while ((ch = getchar()) != EOF && ch != '\n') {
        if (len + 2 > *cap) {
            *cap = *cap ? 2 * *cap : 4096;
            *buf = xrealloc(*buf, *cap);
        }
        (*buf)[len++] = (char)ch;
    }
    if (ch == EOF && len == 0)
        return -1;
    if (!*buf)
        *buf = xrealloc(NULL, *cap = 16);
    (*buf)[len] = '\0';
    return (long)len;
}

static void write_json_string(const char *s)
{
    putchar('"');
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            printf("\\%c", c);
        else if (c < 0x20)
            printf("\\u%04x", c);
        else
            putchar(c);
    }
    putchar('"');
}

static void refuse(const char *why)
{
    fputs("{\"error\": ", stdout);
    write_json_string(why);
    fputs("}\n", stdout);
    fflush(stdout);
}

/* one session after its header: the answer, then chunks until n = 0 (returns 0), or 1
 * when the header is refused */
static int session(const char *line, size_t len, fault_t fault, int many)
{
    char err[256] = {0};
    jval hdr;
    cip_model md;
    const jval *proto, *version, *versions;
    int v2 = 0;

    if (!jparse(line, len, &hdr, err, sizeof err)) {
        char msg[300];
        snprintf(msg, sizeof msg, "cannot read the header: %s", err);
        refuse(msg);
        return 1;
    }
    proto = jget(&hdr, "protocol");
    version = jget(&hdr, "version");
    if (!proto || proto->type != J_STR || strcmp(proto->str, "cipval-chunk") != 0 || !version ||
        version->type != J_NUM || version->num != 1.0) {
        refuse("this engine speaks cipval-chunk version 1 (and 2) only");
        jfree(&hdr);
        return 1;
    }
    if (!build_model(&hdr, fault, &md, err, sizeof err)) {
        refuse(err);
        jfree(&hdr);
        return 1;
    }
    versions = jget(&hdr, "versions");
    if (versions && versions->type == J_ARR)
        for (size_t k = 0; k < versions->n; k++)
            if (versions->items[k].type == J_NUM && versions->items[k].num == 2.0)
                v2 = 1;
    jfree(&hdr);

    const char *suffix = fault == FAULT_LENGTH ? "-length" : fault == FAULT_DELAY ? "-delay" : "";
    if (v2)
        printf("{\"protocol\": \"cipval-chunk\", \"version\": 2, \"engine\": \"%s%s\", "
               "\"integrator\": \"other\", \"order\": 1, \"rod\": \"rigid\"%s}\n",
               ENGINE_NAME, suffix, many ? ", \"sessions\": \"many\"" : "");
    else
        printf("{\"protocol\": \"cipval-chunk\", \"version\": 1, \"engine\": \"%s%s\"%s}\n",
               ENGINE_NAME, suffix, many ? ", \"sessions\": \"many\"" : "");
    fflush(stdout);

    const size_t R = (size_t)md.R, S = (size_t)md.S, U = (size_t)md.U;
    double *start = xrealloc(NULL, R * S * sizeof(double));
    double *prev = calloc(R * U + 1, sizeof(double)); /* delay: control held before */
    double *ctrl = NULL, *out = NULL;
    size_t have = 0;
    int64_t warnings = 0;
    if (!prev)
        die("out of memory");
    for (;;) {
        int64_t n;
        if (!read8(&n, 1))
            die("the input ended inside a session (expected a request frame)");
        if (n == 0)
            break;
        if (n < 0 || (double)n * (double)R * (double)(S > U ? S : U) > 1e10)
            die("request with n = %lld steps is out of range", (long long)n);
        const size_t nn = (size_t)n;
        if (nn > have) {
            ctrl = xrealloc(ctrl, R * nn * U * sizeof(double));
            out = xrealloc(out, R * nn * S * sizeof(double));
            have = nn;
        }
        if (!read8(start, R * S) || !read8(ctrl, R * nn * U))
            die("the input ended inside a request frame");
        for (size_t r = 0; r < R; r++) {
            const double *s = start + r * S;
            for (size_t k = 0; k < nn; k++) {
                const double *u = ctrl + (r * nn + k) * U;
                if (fault == FAULT_DELAY)
                    u = k == 0 ? prev + r * U : u - U;
                double *o = out + (r * nn + k) * S;
                step(&md, s, u, o);
                for (size_t j = 0; j < S; j++)
                    if (!isfinite(o[j])) {
                        warnings++;
                        break;
                    }
                s = o;
            }
            if (fault == FAULT_DELAY)
                memcpy(prev + r * U, ctrl + (r * nn + nn - 1) * U, U * sizeof(double));
        }
        write8(&warnings, 1);
        write8(out, R * nn * S);
        if (fflush(stdout) != 0)
            die("cannot write to stdout");
    }
    free(start);
    free(prev);
    free(ctrl);
    free(out);
    return 0;
}

static void usage(FILE *f)
{
    fprintf(f, "usage: cip_engine [--fault length|delay] [--one-session]\n"
               "A CIP engine for cipval's chunk exchange protocol on stdin/stdout.\n"
               "  --fault length   pendulum length 1.005 L in the dynamics\n"
               "  --fault delay    each control applied one step late\n"
               "  --one-session    exit after one session (no \"sessions\": \"many\")\n");
}

int main(int argc, char **argv)
{
    fault_t fault = FAULT_NONE;
    int many = 1;
    char *line = NULL;
    size_t cap = 0;
    for (int a = 1; a < argc; a++) {
        const char *arg = argv[a], *val = NULL;
        if (strcmp(arg, "--fault") == 0 && a + 1 < argc)
            val = argv[++a];
        else if (strncmp(arg, "--fault=", 8) == 0)
            val = arg + 8;
        else if (strcmp(arg, "--one-session") == 0) {
            many = 0;
            continue;
        } else if (strcmp(arg, "-h") == 0 || strcmp(arg, "--help") == 0) {
            usage(stdout);
            return 0;
        } else {
            usage(stderr);
            return 2;
        }
        if (strcmp(val, "length") == 0)
            fault = FAULT_LENGTH;
        else if (strcmp(val, "delay") == 0)
            fault = FAULT_DELAY;
        else if (strcmp(val, "none") != 0) {
            usage(stderr);
            return 2;
        }
    }
    for (;;) {
        long len = read_line(&line, &cap);
        if (len < 0) /* cipval closed our stdin: no further session */
            break;
        int status = session(line, (size_t)len, fault, many);
        if (status || !many) {
            free(line);
            return status;
        }
    }
    free(line);
    return 0;
}

/* haa_sym column driver (codegen/driver.c, appended to the generated C by `make derive`).
 *
 * Grid sweeps evaluate one generated function on tens of thousands of gain points. Called
 * through CasADi, every point (column) is a separate dispatch that costs about as much as the
 * Schur-Cohn test itself; this loop runs all columns in one C call. Inputs other than the
 * column input are shared by every point. Column-major (CasADi's dense layout) throughout.
 */
#include <math.h>
#include <stdlib.h>

typedef int (*haa_fn)(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w,
                      int mem);
typedef int (*haa_work_fn)(casadi_int* sz_arg, casadi_int* sz_res, casadi_int* sz_iw,
                           casadi_int* sz_w);

/* f, work: a generated function and its _work query; args[n_in]: inputs, args[col] holding
 * n_cols columns of col_stride reals; outs[n_out]: outputs, column k of output i at
 * outs[i] + k * out_stride[i]. Returns 0, 1 if f failed, 2 if out of memory. */
CASADI_SYMBOL_EXPORT int haa_columns(void* f, void* work, casadi_int n_in,
                                     const casadi_real** args, casadi_int col,
                                     casadi_int col_stride, casadi_int n_cols, casadi_int n_out,
                                     casadi_real** outs, const casadi_int* out_stride) {
  casadi_int sz_arg, sz_res, sz_iw, sz_w, k, i;
  int flag = 0;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* w;
  ((haa_work_fn)work)(&sz_arg, &sz_res, &sz_iw, &sz_w);
  if (sz_arg < n_in) sz_arg = n_in;
  if (sz_res < n_out) sz_res = n_out;
  arg = (const casadi_real**)malloc(sizeof(casadi_real*) * sz_arg);
  res = (casadi_real**)malloc(sizeof(casadi_real*) * sz_res);
  iw = (casadi_int*)malloc(sizeof(casadi_int) * (sz_iw > 0 ? sz_iw : 1));
  w = (casadi_real*)malloc(sizeof(casadi_real) * (sz_w > 0 ? sz_w : 1));
  if (!arg || !res || !iw || !w) {
    flag = 2;
  } else {
    for (k = 0; k < n_cols; ++k) {
      for (i = 0; i < n_in; ++i) arg[i] = args[i];
      arg[col] = args[col] + k * col_stride;
      for (i = 0; i < n_out; ++i) res[i] = outs[i] + k * out_stride[i];
      if (((haa_fn)f)(arg, res, iw, w, 0)) {
        flag = 1;
        break;
      }
    }
  }
  free(arg);
  free(res);
  free(iw);
  free(w);
  return flag;
}

/* haa_simulate: the nonlinear simulation's sample loop (haa_sym.analysis.simulate).
 *
 * Per sample k: sample(x, xc, exo_k, ctrl) -> (u, xc_next, y_k), then the plant runs over the
 * sample interval in n_pieces pieces (1, or 2 with a fractional drive delay), each piece p by
 * step(x, u_p, s_p, plant + p plant_stride) applied n_sub times (the exact ZOH transition once,
 * or n_sub integrating substeps). The drive's dead time, whole Ts + f (haa_sym.loop.plant,
 * delay_split): the commands u[0] of the samples are a delay line (a ring of whole + n_pieces
 * reals, zero before t = 0); piece p holds command k - whole - (n_pieces - 1 - p), so with two
 * pieces the older command for the first f seconds and the newer for the rest (the modified
 * z-transform's switch, exactly); every other entry of u_p is u's own (the external torque is
 * not delayed). s_p = delta_k piece_frac[p]: the jitter stretches each piece in proportion to
 * its length (piece_frac: f/Ts and 1 - f/Ts, or 1). One C call runs a whole chunk: a call of a
 * generated function through CasADi costs more than the step itself. x (nx) and xc (nc) hold
 * the initial state and return the final one; exo holds n_steps columns of n_exo reals (delta
 * is its last row); y receives n_steps columns of n_y reals; xpeak (nx reals, or NULL) receives
 * max_k |x_i| over the sample instants. carry (3 + whole + n_pieces reals, or NULL) receives the
 * delay line at the end, and with carry_in = 1 gives it at the start (haa_carry_out: a run
 * continued from the state where the last one stopped). Returns 0, 1 if a function failed, 2 if
 * out of memory, 3 if n_pieces < 1 or whole < 0. */
/* The work arrays of the sample loops: the sample function and the plant step are called in
 * turn, so arg, res, iw and w are sized for the larger of the two; w carries `extra` more reals
 * after the functions' own (the loop's vectors, from haa_work.extra). */
typedef struct {
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real* w;
  casadi_real* extra;
} haa_work;

static void haa_work_free(haa_work* m) {
  free(m->arg);
  free(m->res);
  free(m->iw);
  free(m->w);
}

/* 0, or 2 if out of memory (what was allocated is freed) */
static int haa_work_alloc(void* sample_work, void* step_work, casadi_int extra, haa_work* m) {
  casadi_int a1, r1, i1, w1, a2, r2, i2, w2, sz_arg, sz_res, sz_iw, sz_w;
  ((haa_work_fn)sample_work)(&a1, &r1, &i1, &w1);
  ((haa_work_fn)step_work)(&a2, &r2, &i2, &w2);
  sz_arg = a1 > a2 ? a1 : a2;
  sz_res = r1 > r2 ? r1 : r2;
  sz_iw = i1 > i2 ? i1 : i2;
  sz_w = w1 > w2 ? w1 : w2;
  if (sz_arg < 4) sz_arg = 4;
  if (sz_res < 3) sz_res = 3;
  if (sz_w < 1) sz_w = 1;
  m->arg = (const casadi_real**)malloc(sizeof(casadi_real*) * sz_arg);
  m->res = (casadi_real**)malloc(sizeof(casadi_real*) * sz_res);
  m->iw = (casadi_int*)malloc(sizeof(casadi_int) * (sz_iw > 0 ? sz_iw : 1));
  m->w = (casadi_real*)malloc(sizeof(casadi_real) * (sz_w + extra));
  if (!m->arg || !m->res || !m->iw || !m->w) {
    haa_work_free(m);
    return 2;
  }
  m->extra = m->w + sz_w;
  return 0;
}

/* one sample instant: sample(x, xc, e, ctrl) -> (u, xc_next, yk), then xc = xc_next (through
 * xc2, nc reals); 1 if the function failed */
static int haa_sample(void* sample, haa_work* m, const casadi_real* x, casadi_real* xc,
                      casadi_real* xc2, casadi_int nc, const casadi_real* e,
                      const casadi_real* ctrl, casadi_real* u, casadi_real* yk) {
  casadi_int j;
  m->arg[0] = x;
  m->arg[1] = xc;
  m->arg[2] = e;
  m->arg[3] = ctrl;
  m->res[0] = u;
  m->res[1] = xc2;
  m->res[2] = yk;
  if (((haa_fn)sample)(m->arg, m->res, m->iw, m->w, 0)) return 1;
  for (j = 0; j < nc; ++j) xc[j] = xc2[j];
  return 0;
}

/* The drive's delay line (see haa_simulate): a ring of whole + n_pieces commands, newest at head */
typedef struct {
  casadi_real* ring;
  casadi_int size, head, whole, n_pieces;
} haa_delay;

/* push u[0] of this sample; then up (n_pieces x n_u) = u with its command delayed per piece and
 * s (n_pieces) = delta piece_frac */
static void haa_delay_pieces(haa_delay* d, const casadi_real* u, casadi_int n_u, casadi_real delta,
                             const casadi_real* piece_frac, casadi_real* up, casadi_real* s) {
  casadi_int p, i, j;
  d->head = (d->head + 1) % d->size;
  d->ring[d->head] = u[0];
  for (p = 0; p < d->n_pieces; ++p) {
    j = d->whole + (d->n_pieces - 1 - p);
    for (i = 0; i < n_u; ++i) up[p * n_u + i] = u[i];
    up[p * n_u] = d->ring[(d->head - j + d->size) % d->size];
    s[p] = delta * piece_frac[p];
  }
}

/* the delay line as the previous segment left it (carry: see haa_carry_out), or empty (carry NULL) */
static void haa_delay_init(haa_delay* d, casadi_real* ring, casadi_int whole, casadi_int n_pieces,
                           const casadi_real* carry) {
  casadi_int i;
  d->ring = ring;
  d->size = whole + n_pieces;
  d->head = carry ? (casadi_int)carry[2] : 0;
  d->whole = whole;
  d->n_pieces = n_pieces;
  for (i = 0; i < d->size; ++i) ring[i] = carry ? carry[3 + i] : 0;
}

/* The loop's state besides x and xc, so that a run continues where the last segment stopped
 * (haa_sym.analysis.simulate, Continuation): carry = [lev, err_last, head, ring[0 .. whole +
 * n_pieces - 1]] (3 + whole + n_pieces reals), read at the start when carry_in is 1 and written
 * at the end (lev and err_last: haa_simulate_adaptive's level kept last and its difference;
 * head and ring: the drive's delay line). A run of n1 samples and its continuation over n2
 * then take exactly the steps of one run of n1 + n2 samples. */
static void haa_carry_out(casadi_real* carry, const haa_delay* d, casadi_int lev, casadi_real err_last) {
  casadi_int i;
  if (!carry) return;
  carry[0] = (casadi_real)lev;
  carry[1] = err_last;
  carry[2] = (casadi_real)d->head;
  for (i = 0; i < d->size; ++i) carry[3 + i] = d->ring[i];
}

CASADI_SYMBOL_EXPORT int haa_simulate(void* sample, void* sample_work, void* step, void* step_work,
                                      casadi_int n_sub, casadi_int nx, casadi_int nc, casadi_int n_u,
                                      casadi_real* x, casadi_real* xc, const casadi_real* exo,
                                      casadi_int n_exo, const casadi_real* ctrl,
                                      const casadi_real* plant, casadi_real* y, casadi_int n_y,
                                      casadi_real* xpeak, casadi_int n_steps, casadi_int n_pieces,
                                      casadi_int plant_stride, const casadi_real* piece_frac,
                                      casadi_int whole, casadi_real* carry, casadi_int carry_in) {
  casadi_int k, j, p;
  int flag;
  haa_work m;
  haa_delay d;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real *w, *u, *x2, *xc2, *up, *sp;
  if (n_pieces < 1 || whole < 0) return 3;
  flag = haa_work_alloc(sample_work, step_work,
                        n_u + nx + nc + n_pieces * (n_u + 1) + whole + n_pieces, &m);
  if (!flag) {
    arg = m.arg;
    res = m.res;
    iw = m.iw;
    w = m.w;
    u = m.extra;
    x2 = u + n_u;
    xc2 = x2 + nx;
    up = xc2 + nc;
    sp = up + n_pieces * n_u;
    haa_delay_init(&d, sp + n_pieces, whole, n_pieces, carry_in ? carry : NULL);
    if (xpeak)
      for (j = 0; j < nx; ++j) xpeak[j] = 0;
    for (k = 0; k < n_steps && !flag; ++k) {
      const casadi_real* e = exo + k * n_exo;
      if (xpeak)
        for (j = 0; j < nx; ++j) xpeak[j] = fabs(x[j]) > xpeak[j] ? fabs(x[j]) : xpeak[j];
      if (haa_sample(sample, &m, x, xc, xc2, nc, e, ctrl, u, y + k * n_y)) {
        flag = 1;
        break;
      }
      haa_delay_pieces(&d, u, n_u, e[n_exo - 1], piece_frac, up, sp);
      for (p = 0; p < n_pieces && !flag; ++p) {
        for (j = 0; j < n_sub; ++j) {
          arg[0] = x;
          arg[1] = up + p * n_u;
          arg[2] = sp + p;
          arg[3] = plant + p * plant_stride;
          res[0] = x2;
          if (((haa_fn)step)(arg, res, iw, w, 0)) {
            flag = 1;
            break;
          }
          {
            casadi_int i;
            for (i = 0; i < nx; ++i) x[i] = x2[i];
          }
        }
      }
    }
    haa_carry_out(carry, &d, 0, 0);
    haa_work_free(&m);
  }
  return flag;
}

/* haa_simulate_adaptive: haa_simulate with the plant step's substeps chosen per sample.
 *
 * plant holds n_slopes^n_rows tables of n_levels parameter vectors of plant_size reals: level j
 * for 2^j substeps per sample. The table is chosen at the start of each substep from the
 * friction rows (stick_rows: n_rows rows of nx reals, v_r = stick_rows[r] . x = velocity / v_s): digit r
 * (base n_slopes) is the index of the entry of slopes nearest to 1 - tanh(v_r)^2, the tanh
 * model's slope there relative to its slope at v = 0 (that slope sits in the table's exact
 * linear part).
 * Per sample the state is advanced at two adjacent levels j and j + 1 (step doubling);
 * the finer result is kept when max_i |x_j - x_(j+1)|_i / scale_i <= tol (or at the finest
 * level), else j grows. The next sample tests the pair one level coarser than the one this
 * sample kept (j_next = j_kept - 1 ... j_kept, so that its kept level can be j_kept), two
 * coarser (kept level j_kept - 1) when this sample's difference was below tol / HAA_DROP: a
 * fourth-order step's difference shrinks 16-fold per level, so the coarser pair is then
 * predicted within tol (HAA_DROP = 32, a factor 2 of margin); the test itself is unchanged.
 * With a drive delay the sample runs in n_pieces pieces as in haa_simulate, both at the level
 * tested (2^lev substeps each), piece p from its own tables at plant + p plant_stride: with a
 * fractional delay the substeps end exactly at the command's switch.
 * levels receives the level used per sample (as a real). carry and carry_in as haa_simulate's,
 * with the level kept last and its difference too. Returns as haa_simulate; 3 if
 * n_levels < 2, n_pieces < 1 or whole < 0. */
#define HAA_DROP 32.0
/* the table of the friction's slopes at x (see haa_simulate_adaptive) */
static const casadi_real* haa_table(const casadi_real* plant, casadi_int n_levels,
                                    casadi_int plant_size, const casadi_real* x, casadi_int nx,
                                    const casadi_real* rows, casadi_int n_rows,
                                    const casadi_real* slopes, casadi_int n_slopes) {
  casadi_int index = 0, r, q, i, radix = 1;
  for (r = 0; r < n_rows; ++r) {
    casadi_real v = 0, f, best = 2;
    casadi_int pick = 0;
    for (i = 0; i < nx; ++i) v += rows[r * nx + i] * x[i];
    f = tanh(v);
    f = 1 - f * f;
    for (q = 0; q < n_slopes; ++q)
      if (fabs(f - slopes[q]) < best) {
        best = fabs(f - slopes[q]);
        pick = q;
      }
    index += pick * radix;
    radix *= n_slopes;
  }
  return plant + index * n_levels * plant_size;
}

/* x = x0 advanced by n_sub = 2^lev substeps, each with the table of the slopes at its start */
static int haa_advance(void* step, const casadi_real** arg, casadi_real** res, casadi_int* iw,
                       casadi_real* w, const casadi_real* x0, const casadi_real* u,
                       const casadi_real* s, const casadi_real* plant, casadi_int lev,
                       casadi_int n_levels, casadi_int plant_size, const casadi_real* rows,
                       casadi_int n_rows, const casadi_real* slopes, casadi_int n_slopes,
                       casadi_int nx, casadi_real* x, casadi_real* tmp) {
  casadi_int j, i, n_sub = (casadi_int)1 << lev;
  if (x != x0)
    for (i = 0; i < nx; ++i) x[i] = x0[i];
  for (j = 0; j < n_sub; ++j) {
    arg[0] = x;
    arg[1] = u;
    arg[2] = s;
    arg[3] = haa_table(plant, n_levels, plant_size, x, nx, rows, n_rows, slopes, n_slopes) +
             lev * plant_size;
    res[0] = tmp;
    if (((haa_fn)step)(arg, res, iw, w, 0)) return 1;
    for (i = 0; i < nx; ++i) x[i] = tmp[i];
  }
  return 0;
}

/* x = x0 advanced over the whole sample: piece p (held input up + p n_u, jitter share s + p,
 * tables at plant + p plant_stride) at level lev each */
static int haa_advance_pieces(void* step, const casadi_real** arg, casadi_real** res, casadi_int* iw,
                              casadi_real* w, const casadi_real* x0, const casadi_real* up,
                              const casadi_real* s, const casadi_real* plant, casadi_int plant_stride,
                              casadi_int n_pieces, casadi_int n_u, casadi_int lev, casadi_int n_levels,
                              casadi_int plant_size, const casadi_real* rows, casadi_int n_rows,
                              const casadi_real* slopes, casadi_int n_slopes, casadi_int nx,
                              casadi_real* x, casadi_real* tmp) {
  casadi_int p;
  for (p = 0; p < n_pieces; ++p)
    if (haa_advance(step, arg, res, iw, w, p ? x : x0, up + p * n_u, s + p, plant + p * plant_stride,
                    lev, n_levels, plant_size, rows, n_rows, slopes, n_slopes, nx, x, tmp))
      return 1;
  return 0;
}

CASADI_SYMBOL_EXPORT int haa_simulate_adaptive(
    void* sample, void* sample_work, void* step, void* step_work, casadi_int n_levels,
    casadi_int plant_size, casadi_int nx, casadi_int nc, casadi_int n_u, casadi_real* x,
    casadi_real* xc, const casadi_real* exo, casadi_int n_exo, const casadi_real* ctrl,
    const casadi_real* plant, const casadi_real* scale, casadi_real tol,
    const casadi_real* stick_rows, casadi_int n_rows, const casadi_real* slopes,
    casadi_int n_slopes, casadi_real* y,
    casadi_int n_y, casadi_real* levels, casadi_int n_steps, casadi_int n_pieces,
    casadi_int plant_stride, const casadi_real* piece_frac, casadi_int whole, casadi_real* carry,
    casadi_int carry_in) {
  casadi_int k, i, lev = 0;
  int flag;
  haa_work m;
  haa_delay d;
  const casadi_real** arg;
  casadi_real** res;
  casadi_int* iw;
  casadi_real *w, *u, *xa, *xb, *tmp, *xc2, *up, *sp;
  casadi_real err_last = tol + 1; /* no prediction before the first sample */
  if (n_levels < 2 || n_pieces < 1 || whole < 0) return 3;
  flag = haa_work_alloc(sample_work, step_work,
                        n_u + 3 * nx + nc + n_pieces * (n_u + 1) + whole + n_pieces, &m);
  if (!flag) {
    arg = m.arg;
    res = m.res;
    iw = m.iw;
    w = m.w;
    u = m.extra;
    xa = u + n_u;
    xb = xa + nx;
    tmp = xb + nx;
    xc2 = tmp + nx;
    up = xc2 + nc;
    sp = up + n_pieces * n_u;
    haa_delay_init(&d, sp + n_pieces, whole, n_pieces, carry_in ? carry : NULL);
    if (carry && carry_in) {
      lev = (casadi_int)carry[0];
      err_last = carry[1];
    }
    for (k = 0; k < n_steps && !flag; ++k) {
      const casadi_real* e = exo + k * n_exo;
      if (haa_sample(sample, &m, x, xc, xc2, nc, e, ctrl, u, y + k * n_y)) {
        flag = 1;
        break;
      }
      haa_delay_pieces(&d, u, n_u, e[n_exo - 1], piece_frac, up, sp);
      /* lev is the level kept last; test (lev - 1, lev), or (lev - 2, lev - 1) when the last
       * difference predicts it within tol */
      lev -= (err_last <= tol / HAA_DROP) ? 2 : 1;
      if (lev < 0) lev = 0;
      if (lev > n_levels - 2) lev = n_levels - 2;
      flag = haa_advance_pieces(step, arg, res, iw, w, x, up, sp, plant, plant_stride, n_pieces, n_u,
                                lev, n_levels, plant_size, stick_rows, n_rows, slopes, n_slopes, nx,
                                xa, tmp);
      while (!flag) {
        casadi_real err = 0;
        flag = haa_advance_pieces(step, arg, res, iw, w, x, up, sp, plant, plant_stride, n_pieces,
                                  n_u, lev + 1, n_levels, plant_size, stick_rows, n_rows, slopes,
                                  n_slopes, nx, xb, tmp);
        if (flag) break;
        for (i = 0; i < nx; ++i) {
          casadi_real d = (xa[i] - xb[i]) / scale[i];
          if (d < 0) d = -d;
          if (!(d <= err)) err = d; /* NaN propagates as a failure to converge */
        }
        if (err <= tol || lev + 2 >= n_levels) {
          ++lev;
          err_last = err;
          break;
        }
        for (i = 0; i < nx; ++i) xa[i] = xb[i];
        ++lev;
      }
      for (i = 0; i < nx; ++i) x[i] = xb[i];
      levels[k] = (casadi_real)lev;
    }
    haa_carry_out(carry, &d, lev, err_last);
    haa_work_free(&m);
  }
  return flag;
}

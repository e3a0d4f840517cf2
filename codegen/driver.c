/* haa_sym column driver (codegen/driver.c, appended to the generated C by `make derive`).
 *
 * Grid sweeps evaluate one generated function on tens of thousands of gain points. Called
 * through CasADi, every point (column) is a separate dispatch that costs about as much as the
 * Schur-Cohn test itself; this loop runs all columns in one C call. Inputs other than the
 * column input are shared by every point. Column-major (CasADi's dense layout) throughout.
 */
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

/* @NAME@_path.c: the desired path's signals and the step in one call (acroboter.codegen.fast_step). */
int @NAME@(const double** arg, double** res, long long int* iw, double* w, int mem);
int @NAME@_run(const double* tab, double t, double* signals, const double** arg, double** res, long long int* iw,
               double* w);

@PATH@
int @NAME@_run(const double* tab, double t, double* signals, const double** arg, double** res, long long int* iw,
               double* w) {
  @NAME@_flat(tab, t, signals);
  return @NAME@(arg, res, iw, w, 0);
}

/* The spec's desired path as C: acroboter.control.path.DesiredPath.flat, statement for statement (the same IEEE
 * operations in the same order: the same bits), from the path's numbers in a table (acroboter.control.fast_path
 * path_table): rest-to-rest quintic edges through the waypoints, the yaw one quintic over the whole path, the moving
 * anchors following the path's x and y.
 *
 * table: [edges E, signals ns, path index p, followers F, duration D, start yaw, yaw turn, t0[E], dur[E],
 *         origin[3E], delta[3E], template[3 ns], (signal index, axis, offset)[F]]
 * out[3 ns] = [s; sd; sdd] at t (s): the signals in the layout's order. */

static void @NAME@_quintic(double tau, double* s, double* ds, double* dds) {
  double t2;
  if (tau <= 0.0) {
    *s = 0.0;
    *ds = 0.0;
    *dds = 0.0;
    return;
  }
  if (tau >= 1.0) {
    *s = 1.0;
    *ds = 0.0;
    *dds = 0.0;
    return;
  }
  t2 = tau * tau;
  *s = t2 * tau * (10.0 - 15.0 * tau + 6.0 * t2);
  *ds = 30.0 * t2 * (1.0 - 2.0 * tau + t2);
  *dds = 60.0 * tau * (1.0 - 3.0 * tau + 2.0 * t2);
}

@API@void @NAME@_flat(const double* tab, double t, double* out) {
  long long E = (long long)tab[0], ns = (long long)tab[1], p = (long long)tab[2], F = (long long)tab[3];
  double D = tab[4], start_yaw = tab[5], turn = tab[6];
  const double *t0 = tab + 7, *dur = t0 + E, *origin = dur + E, *delta = origin + 3 * E;
  const double *tmpl = delta + 3 * E, *follow = tmpl + 3 * ns;
  long long lo = 0, hi = E, k, i, j, v = ns + p, a = 2 * ns + p;
  double T, s, ds, dds, y, yd, ydd;
  while (lo < hi) { /* bisect.bisect_right */
    long long mid = (lo + hi) / 2;
    if (t < t0[mid]) hi = mid;
    else lo = mid + 1;
  }
  k = lo - 1;
  k = k < 0 ? 0 : (k > E - 1 ? E - 1 : k);
  T = dur[k];
  @NAME@_quintic((t - t0[k]) / T, &s, &ds, &dds);
  ds /= T;
  dds /= T * T;
  @NAME@_quintic(t / D, &y, &yd, &ydd);
  for (i = 0; i < 3 * ns; ++i) out[i] = tmpl[i];
  for (i = 0; i < 3; ++i) {
    out[p + i] = origin[3 * k + i] + s * delta[3 * k + i];
    out[v + i] = ds * delta[3 * k + i];
    out[a + i] = dds * delta[3 * k + i];
  }
  out[p + 3] = start_yaw + turn * y;
  out[v + 3] = turn * yd / D;
  out[a + 3] = turn * ydd / (D * D);
  for (j = 0; j < F; ++j) {
    long long at = (long long)follow[3 * j], c = (long long)follow[3 * j + 1];
    out[at] = follow[3 * j + 2] + out[p + c];
    out[at + v - p] = out[v + c];
    out[at + a - p] = out[a + c];
  }
}

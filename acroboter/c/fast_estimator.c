/* @NAME@: the fast path's estimator (acroboter.codegen.estimator_c, rendered from acroboter/c/). Generated:
 * do not edit. */
#include <math.h>
#include <stddef.h>
#include "@NAME@_functions.h"

@STRUCT@
@CODE@
/* sizeof the struct, then the byte offset of each field the Python binding reads (OFFSET_FIELDS' order). */
void @NAME@_offsets(long long* out);
void @NAME@_offsets(long long* out) {
  out[0] = (long long)sizeof(@NAME@_estimator);
@OFFSETS@
}

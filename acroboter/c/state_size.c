/* sizeof the exported controller's state struct, for a caller that binds it without a C compiler of its own
 * (acroboter.runtime.exported). */
#include <stddef.h>
#include "@NAME@.h"

size_t @NAME@_state_size(void) { return sizeof(@NAME@_state); }

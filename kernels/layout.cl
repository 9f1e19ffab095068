/* Layout probe (tests/test_layout.py): what the OpenCL C compiler sees of the constants and
 * records that clraster/base/layout.py generates into common.h.
 *
 * The test builds this file through the renderer's own path (clraster.device.program, so
 * common.h and its generated part are inlined exactly as for every stage) with
 * -DLAYOUT_PROBE=e0,e1,... : a comma-separated list of C integer expressions — the value of
 * each #define (float ones as their bits), sizeof and offsetof of each record and its fields —
 * and compares the numbers written here with NumPy's dtypes and the Python constants.
 */
#include "common.h"

#ifndef LAYOUT_PROBE
#error "LAYOUT_PROBE must be defined (see tests/test_layout.py)"
#endif

__kernel void layout_probe(__global long *out)
{
    const long v[] = {LAYOUT_PROBE};
    for (int i = 0; i < (int)(sizeof(v) / sizeof(v[0])); ++i) out[i] = v[i];
}

/* Registration of the tacrom.tactile sensor plugin, and the only place that raises MuJoCo
 * errors and warnings.
 *
 * The callbacks are Rust functions (src/mujoco/plugin.rs); "tacrom.h" is generated from
 * them by build.rs. Those that can fail return a status and a message; the wrappers here
 * turn an error into mju_error and a warning into mju_warning after the Rust call has
 * returned, so no Rust frame is ever on the stack when MuJoCo unwinds. Those that cannot
 * fail are registered as they are. */
#include <string.h>

#include <mujoco/mujoco.h>

#include "tacrom.h"

/* Size of the message buffers passed to Rust. */
#define TACROM_MSG_LEN 1000

static int nsensordata(const mjModel* m, int instance, int sensor_id) {
  char msg[TACROM_MSG_LEN] = {0};
  int n = tacrom_nsensordata(m, instance, sensor_id, msg, sizeof(msg));
  if (n < 0) {
    mju_error("%s", msg);
    return 0;
  }
  return n;
}

static int init(const mjModel* m, mjData* d, int instance) {
  char msg[TACROM_MSG_LEN] = {0};
  int status = tacrom_init(m, d, instance, msg, sizeof(msg));
  if (status == TACROM_ERROR) {
    mju_error("%s", msg);
    return -1;
  }
  if (status == TACROM_WARN) {
    mju_warning("%s", msg);
  }
  return 0;
}

static void copy(mjData* dest, const mjModel* m, const mjData* src, int instance) {
  char msg[TACROM_MSG_LEN] = {0};
  if (tacrom_copy(dest, m, src, instance, msg, sizeof(msg)) != TACROM_OK) {
    mju_warning("%s", msg);
  }
}

static void compute(const mjModel* m, mjData* d, int instance, int capability_bit) {
  char msg[TACROM_MSG_LEN] = {0};
  /* Compute never raises an error: a failed evaluation writes zeros and warns, so one bad
   * frame cannot take down a long simulation. The passive stage applies the coupling. */
  int status = capability_bit == mjPLUGIN_PASSIVE
                   ? tacrom_passive(m, d, instance, msg, sizeof(msg))
                   : tacrom_compute(m, d, instance, msg, sizeof(msg));
  if (status != TACROM_OK && msg[0]) {
    mju_warning("%s", msg);
  }
}

mjPLUGIN_LIB_INIT(tacrom) {
  mjpPlugin plugin;
  mjp_defaultPlugin(&plugin);
  plugin.name = TACROM_PLUGIN_NAME;
  /* Passive: the optional coupling, which pushes the bodies back (coupling="on"). */
  plugin.capabilityflags |= mjPLUGIN_SENSOR | mjPLUGIN_PASSIVE;
  plugin.needstage = mjSTAGE_POS;
  plugin.attributes = tacrom_attributes(&plugin.nattribute);
  plugin.nstate = tacrom_nstate;
  plugin.nsensordata = nsensordata;
  plugin.init = init;
  plugin.destroy = tacrom_destroy;
  plugin.copy = copy;
  plugin.reset = tacrom_reset;
  plugin.compute = compute;
  plugin.visualize = tacrom_visualize;
  mjp_registerPlugin(&plugin);
}

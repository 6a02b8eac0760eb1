/* The Rust half of the tacrom plugin, as the C shim sees it.
 *
 * Every function here is implemented in Rust (src/mujoco/plugin.rs), catches panics, and
 * reports failure through its return value and a message buffer: Rust never calls
 * mju_error, because mju_error longjmps or throws over the frames that called it. The shim
 * (tacrom_shim.c) raises the message once the Rust frames are gone. */
#ifndef TACROM_H_
#define TACROM_H_

#include <mujoco/mujoco.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Size of the message buffers the shim passes to Rust. */
#define TACROM_MSG_LEN 1000

/* Return codes. */
#define TACROM_OK 0
#define TACROM_WARN 1  /* success, with a warning in the message buffer */
#define TACROM_ERROR -1

/* The plugin's configuration attribute names; *count receives their number. */
const char* const* tacrom_attributes(int* count);

int tacrom_nstate(const mjModel* m, int instance);
/* >= 0: the sensor's dimension; TACROM_ERROR: invalid configuration, see msg. */
int tacrom_nsensordata(const mjModel* m, int instance, int sensor_id, char* msg, int len);
int tacrom_init(const mjModel* m, mjData* d, int instance, char* msg, int len);
void tacrom_destroy(mjData* d, int instance);
int tacrom_copy(mjData* dest, const mjModel* m, const mjData* src, int instance, char* msg,
                int len);
void tacrom_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data, int instance);
int tacrom_compute(const mjModel* m, mjData* d, int instance, char* msg, int len);
/* The coupling: adds the gel's contact wrenches to qfrc_passive (coupling="on"). */
int tacrom_passive(const mjModel* m, mjData* d, int instance, char* msg, int len);
/* Adds the sensor's geoms to the scene when opt shows contact points or forces. */
void tacrom_visualize(const mjModel* m, mjData* d, const mjvOption* opt, mjvScene* scn,
                      int instance);
/* The sensordata layout of a sensor as JSON (for the Python package); see plugin.rs. */
int tacrom_sensor_outputs(const mjModel* m, int sensor_id, char* buf, int len);
/* The output table as JSON (for the Python package); see plugin.rs. */
int tacrom_output_table(char* buf, int len);
/* The attribute table as JSON (for the Python package); see plugin.rs. */
int tacrom_attribute_table(char* buf, int len);

#ifdef __cplusplus
}
#endif

#endif /* TACROM_H_ */

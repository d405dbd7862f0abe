/* The `--ready-file` of the rig's programs (docs/interfaces.md): written once the node is on
 * the bus and ready, atomically (temporary file + rename), holding the process id, so a
 * supervisor that sees the file never reads half of it. */
#ifndef HIL_READY_H
#define HIL_READY_H

#ifdef __cplusplus
extern "C" {
#endif

/* Returns 0, or -1 with errno set. */
int hil_write_ready_file(const char *path);

#ifdef __cplusplus
}
#endif
#endif

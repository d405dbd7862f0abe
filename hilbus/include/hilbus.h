/* hilbus: one CAN interface for the rig's C programs, over two transports.
 *
 *  - "socketcan": Linux SocketCAN raw socket (AF_CAN), CAN FD frames enabled.
 *  - "unixcan":   the userspace fallback for kernels without CAN: the same struct
 *                 canfd_frame over Unix datagram sockets, broadcast to every other node
 *                 of the channel (docs/interfaces.md).
 *
 * Frames are always struct canfd_frame; `fd` says whether it is a CAN FD frame
 * (len up to 64) or a classic one (len up to 8). On unixcan a node opened HILBUS_LOSSLESS
 * (the nodes of a lockstep run) loses no frame: a sender waits while its queue is full (a
 * bounded stall that ends in an error naming it, hilbus_last_error). Any other node is a
 * listener: a listener whose queue stays full costs a counted transmit drop (hilbus_stats,
 * hilbus_listener_drops), never a silent loss, as a SocketCAN socket's overflow does.
 */
#ifndef HILBUS_H
#define HILBUS_H

#include <signal.h>
#include <stddef.h>
#include <stdint.h>
#include <linux/can.h>

#include "hil_unixcan.h" /* generated from protocols/unixcan.toml */

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hilbus hilbus_t;

typedef struct {
    uint64_t tx_frames;     /* frames handed to the transport */
    uint64_t tx_drops;      /* (frame, listener) pairs lost to a full listener (unixcan) */
    uint64_t tx_errors;     /* other send failures */
    uint64_t rx_frames;     /* frames delivered to the caller */
    uint64_t rx_overflows;  /* frames the kernel dropped on our socket (SO_RXQ_OVFL), socketcan only */
    uint64_t rx_filtered;   /* frames received but not matching the filters (unixcan) */
    uint64_t peers_removed; /* unixcan: dead peers removed */
    uint64_t rx_malformed;  /* unixcan: datagrams that are no valid CAN / CAN FD frame (size, len) */
    uint64_t foreign_entries;    /* unixcan: folder entries that are no socket of this user: ignored */
    uint64_t peers_beyond_limit; /* unixcan: most nodes seen beyond HILBUS_MAX_PEERS (not reached) */
    /* unixcan, sending to a lossless node whose queue was full: */
    uint64_t tx_stalls;          /* deliveries that waited */
    uint64_t tx_stall_ns_total;  /* the time they waited, in all */
    uint64_t tx_stall_ns_max;    /* the longest wait */
    uint64_t tx_stall_failures;  /* deliveries given up after HIL_UNIXCAN_LOSSLESS_STALL_NS */
    uint64_t rx_pending_max;     /* most frames taken off the socket while waiting (hilbus_pending) */
} hilbus_stats_t;

/* transport: "socketcan", "unixcan" or "auto" (socketcan when the kernel has the
 * interface, else unixcan). Returns NULL with a message in err on failure. */
hilbus_t *hilbus_open(const char *transport, const char *channel, char *err, size_t errlen);
/* The same with flags: HILBUS_LOSSLESS, on unixcan a node every sender waits for rather than
 * drop a frame for it (its socket's name says so: protocols/unixcan.toml [socket]); the
 * nodes of a lockstep run. On SocketCAN the flag changes nothing (the kernel decides). */
#define HILBUS_LOSSLESS 0x1u
hilbus_t *hilbus_open_flags(const char *transport, const char *channel, unsigned flags, char *err,
                            size_t errlen);
void hilbus_close(hilbus_t *bus);

/* Which transport an open bus uses: "socketcan" or "unixcan". */
const char *hilbus_transport(const hilbus_t *bus);

/* Receive only frames whose (can_id & mask) == (id & mask) for one of the filters
 * (SocketCAN semantics). n = 0 receives everything. Returns 0, or -1 on error. */
int hilbus_set_filters(hilbus_t *bus, const struct can_filter *filters, int n);

/* Send one frame. fd != 0: CAN FD frame (len <= 64, a valid FD length); else classic
 * (len <= 8). Returns 0 when handed over (drops to full listeners are counted, not
 * errors), -1 on an error (invalid frame, socket error) with errno set. On unixcan a
 * lossless node whose queue is full is waited for, the frames sent to this node meanwhile
 * kept for hilbus_recv (so two nodes waiting on each other both go on); after
 * HIL_UNIXCAN_LOSSLESS_STALL_NS it is -1 with errno ETIMEDOUT and hilbus_last_error naming
 * the node (the frame went to every other node), or EINTR once the stop flag is set. */
int hilbus_send(hilbus_t *bus, const struct canfd_frame *frame, int fd);

/* What the last failed send was, in words ("" when none failed). */
const char *hilbus_last_error(const hilbus_t *bus);

/* A flag (the program's stop signal) that ends a wait for a lossless node at once. */
void hilbus_set_stop(hilbus_t *bus, const volatile sig_atomic_t *stop);

/* Frames already taken off the socket (during a send's wait) that hilbus_recv hands on next.
 * A caller that polls hilbus_fileno must not sleep while this is not 0. */
int hilbus_pending(const hilbus_t *bus);

/* Receive one frame, waiting at most timeout_us (0: poll, < 0: wait forever).
 * Returns 1 with *frame and *fd set, 0 on time-out, -1 on error. */
int hilbus_recv(hilbus_t *bus, struct canfd_frame *frame, int *fd, int64_t timeout_us);

/* Busy-poll for up to spin_us microseconds before sleeping in hilbus_recv. A sleeping
 * receiver costs a scheduler wake-up per frame (tens of µs on a VM); spinning trades CPU
 * for latency. Default: the HILBUS_SPIN_US environment variable, else 0. */
void hilbus_set_spin(hilbus_t *bus, int32_t spin_us);

/* File descriptor to poll() for readability. */
int hilbus_fileno(const hilbus_t *bus);

void hilbus_get_stats(const hilbus_t *bus, hilbus_stats_t *stats);

/* unixcan: the listeners this node dropped frames for, by socket name (at most
 * HILBUS_MAX_LISTENERS named; the drops for further ones under the name "other"). For i in
 * 0..: 1 with *name and *drops set, 0 past the last. */
#define HILBUS_MAX_LISTENERS 16
int hilbus_listener_drops(const hilbus_t *bus, int i, const char **name, uint64_t *drops);

/* Frames per 11-bit identifier (data frames of the standard format: every frame of the
 * rig's protocols): sent = valid frames handed to hilbus_send (whatever the transport then
 * did with them), received = frames hilbus_recv delivered. A receiver never gets more
 * frames of an id than its senders sent: the rig compares them to find frames a node
 * outside the run sent (docs/interfaces.md, "Foreign traffic"). */
#define HILBUS_IDS 2048
uint64_t hilbus_id_sent(const hilbus_t *bus, uint32_t id);
uint64_t hilbus_id_received(const hilbus_t *bus, uint32_t id);

/* Channel names are plain names (no path, no "..", no option): the rule of
 * protocols/unixcan.toml [channel], for both transports. */
#define HILBUS_MAX_CHANNEL HIL_UNIXCAN_CHANNEL_MAX_LEN
/* 1 when `channel` is such a name (hilbus_open refuses the others). */
int hilbus_channel_name_ok(const char *channel);
#define HILBUS_MAX_PEERS 64 /* unixcan: nodes a node sends to; more are counted, not reached */

/* unixcan: the folder holding one sub-folder per channel ($UNIXCAN_DIR, else
 * $XDG_RUNTIME_DIR/unixcan, else /tmp/unixcan-<uid>). 0, or -1 (path too long). */
int hilbus_unixcan_base(char *out, size_t outlen);

/* Rounds a payload length up to the next valid CAN FD length (HIL_UNIXCAN_FD_LENGTHS). */
uint8_t hilbus_fd_len(size_t len);

#ifdef __cplusplus
}
#endif
#endif

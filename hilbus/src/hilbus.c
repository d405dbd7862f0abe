/* hilbus: transport selection, the common receive loop and frame validation. */
#define _GNU_SOURCE
#include <errno.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "hilbus_internal.h"

static const uint8_t fd_lengths[HIL_UNIXCAN_FD_LENGTH_COUNT] = HIL_UNIXCAN_FD_LENGTHS;

uint8_t hilbus_fd_len(size_t len)
{
    for (size_t i = 0; i < sizeof fd_lengths; i++) {
        if (len <= fd_lengths[i]) return fd_lengths[i];
    }
    return HIL_UNIXCAN_FD_MAX_LEN;
}

static int valid_frame(const struct canfd_frame *frame, int fd)
{
    if (fd) return frame->len <= CANFD_MAX_DLEN && hilbus_fd_len(frame->len) == frame->len;
    return frame->len <= CAN_MAX_DLEN;
}

hilbus_t *hilbus_open(const char *transport, const char *channel, char *err, size_t errlen)
{
    return hilbus_open_flags(transport, channel, 0u, err, errlen);
}

hilbus_t *hilbus_open_flags(const char *transport, const char *channel, unsigned flags, char *err,
                            size_t errlen)
{
    if (!hilbus_channel_name_ok(channel)) {
        snprintf(err, errlen, "invalid channel name '%.80s': %s", channel ? channel : "",
                 HIL_UNIXCAN_CHANNEL_RULE);
        return NULL;
    }
    struct hilbus *bus = calloc(1, sizeof *bus);
    if (bus == NULL) {
        snprintf(err, errlen, "out of memory");
        return NULL;
    }
    bus->sock = -1;
    bus->flags = flags & HILBUS_LOSSLESS;
    const char *spin = getenv("HILBUS_SPIN_US");
    if (spin != NULL) bus->spin_us = (int32_t)strtol(spin, NULL, 10);
    if (bus->spin_us < 0) bus->spin_us = 0;
    int want_socketcan;
    if (transport == NULL || strcmp(transport, "auto") == 0) {
        want_socketcan = hilbus_socketcan_available(channel);
    } else if (strcmp(transport, "socketcan") == 0) {
        want_socketcan = 1;
    } else if (strcmp(transport, "unixcan") == 0) {
        want_socketcan = 0;
    } else {
        snprintf(err, errlen, "unknown transport '%s' (socketcan, unixcan or auto)", transport);
        free(bus);
        return NULL;
    }
    int rc = want_socketcan ? hilbus_socketcan_open(bus, channel, err, errlen)
                            : hilbus_unixcan_open(bus, channel, err, errlen);
    if (rc != 0) {
        free(bus);
        return NULL;
    }
    return bus;
}

void hilbus_close(hilbus_t *bus)
{
    if (bus == NULL) return;
    if (bus->kind == HILBUS_UNIXCAN) hilbus_unixcan_close(bus);
    if (bus->sock >= 0) close(bus->sock);
    free(bus->pending);
    free(bus);
}

const char *hilbus_last_error(const hilbus_t *bus) { return bus->last_error; }

void hilbus_set_stop(hilbus_t *bus, const volatile sig_atomic_t *stop) { bus->stop = stop; }

int hilbus_pending(const hilbus_t *bus) { return (int)bus->pend_count; }

int hilbus_listener_drops(const hilbus_t *bus, int i, const char **name, uint64_t *drops)
{
    if (i >= 0 && i < bus->n_listeners) {
        *name = bus->listeners[i].name;
        *drops = bus->listeners[i].drops;
        return 1;
    }
    if (i == bus->n_listeners && bus->listener_drops_other > 0) {
        *name = "other";
        *drops = bus->listener_drops_other;
        return 1;
    }
    return 0;
}

const char *hilbus_transport(const hilbus_t *bus)
{
    return bus->kind == HILBUS_SOCKETCAN ? "socketcan" : "unixcan";
}

int hilbus_fileno(const hilbus_t *bus) { return bus->sock; }

void hilbus_set_spin(hilbus_t *bus, int32_t spin_us) { bus->spin_us = spin_us > 0 ? spin_us : 0; }

void hilbus_get_stats(const hilbus_t *bus, hilbus_stats_t *stats)
{
    *stats = bus->stats;
    if (bus->kind == HILBUS_SOCKETCAN) hilbus_socketcan_drops(bus, stats);
}

int hilbus_set_filters(hilbus_t *bus, const struct can_filter *filters, int n)
{
    if (n < 0 || n > HILBUS_MAX_FILTERS || (n > 0 && filters == NULL)) {
        errno = EINVAL;
        return -1;
    }
    if (bus->kind == HILBUS_SOCKETCAN) return hilbus_socketcan_set_filters(bus, filters, n);
    bus->n_filters = n;
    if (n > 0) memcpy(bus->filters, filters, (size_t)n * sizeof *filters);
    return 0;
}

/* the slot of a frame in the per-id counts, or -1 (extended, remote or error frame) */
static int id_slot(canid_t can_id)
{
    if (can_id & (CAN_EFF_FLAG | CAN_RTR_FLAG | CAN_ERR_FLAG)) return -1;
    return (int)(can_id & CAN_SFF_MASK);
}

uint64_t hilbus_id_sent(const hilbus_t *bus, uint32_t id)
{
    return id < HILBUS_IDS ? bus->sent_by_id[id] : 0;
}

uint64_t hilbus_id_received(const hilbus_t *bus, uint32_t id)
{
    return id < HILBUS_IDS ? bus->received_by_id[id] : 0;
}

int hilbus_send(hilbus_t *bus, const struct canfd_frame *frame, int fd)
{
    if (!valid_frame(frame, fd)) {
        errno = EINVAL;
        bus->stats.tx_errors++;
        return -1;
    }
    const int slot = id_slot(frame->can_id);
    if (slot >= 0) bus->sent_by_id[slot]++; /* before the transport: a frame some peers got */
    int rc = bus->kind == HILBUS_SOCKETCAN ? hilbus_socketcan_send(bus, frame, fd)
                                          : hilbus_unixcan_send(bus, frame, fd);
    if (rc == 0) bus->stats.tx_frames++;
    return rc;
}

static int64_t now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

static int recv_once(hilbus_t *bus, struct canfd_frame *frame, int *fd)
{
    int got = bus->kind == HILBUS_SOCKETCAN ? hilbus_socketcan_recv(bus, frame, fd)
                                            : hilbus_unixcan_recv(bus, frame, fd);
    if (got == 1) {
        const int slot = id_slot(frame->can_id);
        bus->stats.rx_frames++;
        if (slot >= 0) bus->received_by_id[slot]++;
    }
    return got;
}

int hilbus_recv(hilbus_t *bus, struct canfd_frame *frame, int *fd, int64_t timeout_us)
{
    while (bus->pend_count > 0) { /* what a send's wait took off the socket comes first */
        int got = recv_once(bus, frame, fd);
        if (got != 0) return got;
    }
    const int64_t start = now_us();
    const int64_t deadline = timeout_us > 0 ? start + timeout_us : 0;
    if (bus->spin_us > 0 && timeout_us != 0) {
        int64_t spin_end = start + bus->spin_us;
        if (timeout_us > 0 && spin_end > deadline) spin_end = deadline;
        do {
            int got = recv_once(bus, frame, fd);
            if (got != 0) return got;
        } while (now_us() < spin_end);
    }
    for (;;) {
        int wait_ms;
        if (timeout_us < 0) {
            wait_ms = -1;
        } else if (timeout_us == 0) {
            wait_ms = 0;
        } else {
            int64_t left = deadline - now_us();
            if (left < 0) left = 0;
            wait_ms = (int)((left + 999) / 1000);
        }
        struct pollfd p = {.fd = bus->sock, .events = POLLIN};
        int n = poll(&p, 1, wait_ms);
        if (n < 0) {
            if (errno == EINTR) return 0;
            return -1;
        }
        if (n > 0) {
            int got = recv_once(bus, frame, fd);
            if (got != 0) return got;
        }
        if (timeout_us == 0) return 0;
        if (timeout_us > 0 && now_us() >= deadline) return 0;
    }
}

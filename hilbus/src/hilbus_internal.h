/* Private to hilbus: the bus object shared by the two transports. */
#ifndef HILBUS_INTERNAL_H
#define HILBUS_INTERNAL_H

#include <limits.h>
#include <sys/types.h>
#include <sys/un.h>
#include <time.h>

#include "hilbus.h"

#define HILBUS_MAX_FILTERS 32
/* unixcan: frames a node keeps off its socket while it waits for a lossless peer, at most
 * (a wait with more coming in stops taking them; the stall then ends as a stall does) */
#define HILBUS_MAX_PENDING 65536

/* A datagram as it came off the socket: its bytes and its size (any size: checked later). */
struct hilbus_datagram {
    struct canfd_frame frame;
    int size;
};

struct hilbus_listener_drops {
    char name[64];
    uint64_t drops;
};

enum hilbus_kind { HILBUS_SOCKETCAN = 1, HILBUS_UNIXCAN = 2 };

struct hilbus {
    enum hilbus_kind kind;
    int sock;
    hilbus_stats_t stats;
    uint64_t sent_by_id[HILBUS_IDS];     /* hilbus_id_sent */
    uint64_t received_by_id[HILBUS_IDS]; /* hilbus_id_received */
    int32_t spin_us;
    /* socketcan: last SO_RXQ_OVFL value the kernel reported */
    uint32_t kernel_overflows;
    char last_error[256];
    /* unixcan */
    unsigned flags; /* HILBUS_LOSSLESS */
    const volatile sig_atomic_t *stop;
    struct hilbus_datagram *pending; /* a ring of pend_cap: frames taken while waiting */
    size_t pend_head, pend_count, pend_cap;
    int n_listeners;
    struct hilbus_listener_drops listeners[HILBUS_MAX_LISTENERS];
    uint64_t listener_drops_other;
    int n_filters;
    struct can_filter filters[HILBUS_MAX_FILTERS];
    char dir[sizeof(((struct sockaddr_un *)0)->sun_path)];
    struct sockaddr_un self;
    int have_group; /* UNIXCAN_GROUP: folder 0770 and sockets 0660 of that group */
    gid_t group;
    int n_peers;
    struct sockaddr_un peers[HILBUS_MAX_PEERS];
    unsigned char congested[HILBUS_MAX_PEERS]; /* peer was still full after the grace wait */
    unsigned char lossless[HILBUS_MAX_PEERS];  /* peer's name carries the lossless mark */
    unsigned char arbiter[HILBUS_MAX_PEERS];   /* peer is the channel's bit clock */
    int peer_fd[HILBUS_MAX_PEERS];             /* a socket connected to each peer: no path lookup per frame */
    struct timespec dir_mtime;
    struct timespec last_scan;
    int64_t last_check_ns; /* monotonic time of the last directory stat */
};

int hilbus_socketcan_open(struct hilbus *bus, const char *channel, char *err, size_t errlen);
int hilbus_socketcan_available(const char *channel);
int hilbus_socketcan_send(struct hilbus *bus, const struct canfd_frame *frame, int fd);
int hilbus_socketcan_recv(struct hilbus *bus, struct canfd_frame *frame, int *fd);
void hilbus_socketcan_drops(const struct hilbus *bus, hilbus_stats_t *stats);
int hilbus_socketcan_set_filters(struct hilbus *bus, const struct can_filter *filters, int n);

int hilbus_unixcan_open(struct hilbus *bus, const char *channel, char *err, size_t errlen);
void hilbus_unixcan_close(struct hilbus *bus);
int hilbus_unixcan_send(struct hilbus *bus, const struct canfd_frame *frame, int fd);
/* 1 = a frame passing the filters, 0 = a datagram that was consumed but not delivered */
int hilbus_unixcan_recv(struct hilbus *bus, struct canfd_frame *frame, int *fd);

#endif

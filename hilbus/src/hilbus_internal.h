/* Private to hilbus: the bus object shared by the two transports. */
#ifndef HILBUS_INTERNAL_H
#define HILBUS_INTERNAL_H

#include <limits.h>
#include <sys/types.h>
#include <sys/un.h>
#include <time.h>

#include "hilbus.h"

#define HILBUS_MAX_FILTERS 32

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
    /* unixcan */
    int n_filters;
    struct can_filter filters[HILBUS_MAX_FILTERS];
    char dir[sizeof(((struct sockaddr_un *)0)->sun_path)];
    struct sockaddr_un self;
    int have_group; /* UNIXCAN_GROUP: folder 0770 and sockets 0660 of that group */
    gid_t group;
    int n_peers;
    struct sockaddr_un peers[HILBUS_MAX_PEERS];
    unsigned char congested[HILBUS_MAX_PEERS]; /* peer was still full after the grace wait */
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

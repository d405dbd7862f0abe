/* hilbus over Linux SocketCAN: a CAN_RAW socket with CAN FD frames enabled. */
#define _GNU_SOURCE
#include <errno.h>
#include <net/if.h>
#include <stdio.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <sys/uio.h>
#include <unistd.h>

#include <linux/can/raw.h>
#include <linux/sock_diag.h>

#include "hilbus_internal.h"

int hilbus_socketcan_available(const char *channel)
{
    int s = socket(PF_CAN, SOCK_RAW, CAN_RAW);
    if (s < 0) return 0;
    close(s);
    return if_nametoindex(channel) != 0;
}

int hilbus_socketcan_open(struct hilbus *bus, const char *channel, char *err, size_t errlen)
{
    int s = socket(PF_CAN, SOCK_RAW, CAN_RAW);
    if (s < 0) {
        snprintf(err, errlen, "socketcan: socket(PF_CAN): %s%s", strerror(errno),
                 errno == EAFNOSUPPORT ? " (this kernel has no CAN support; use --bus unixcan)" : "");
        return -1;
    }
    unsigned int ifindex = if_nametoindex(channel);
    if (ifindex == 0) {
        snprintf(err, errlen, "socketcan: no interface '%s' (create it: rig bus up %s)", channel, channel);
        close(s);
        return -1;
    }
    int on = 1;
    if (setsockopt(s, SOL_CAN_RAW, CAN_RAW_FD_FRAMES, &on, sizeof on) != 0) {
        snprintf(err, errlen, "socketcan: CAN FD frames not supported on '%s': %s", channel, strerror(errno));
        close(s);
        return -1;
    }
    /* The kernel counts frames it dropped on this socket; we read the count per message. */
    (void)setsockopt(s, SOL_SOCKET, SO_RXQ_OVFL, &on, sizeof on);
    int rcvbuf = 4 << 20;
    (void)setsockopt(s, SOL_SOCKET, SO_RCVBUF, &rcvbuf, sizeof rcvbuf);
    struct sockaddr_can addr;
    memset(&addr, 0, sizeof addr);
    addr.can_family = AF_CAN;
    addr.can_ifindex = (int)ifindex;
    if (bind(s, (struct sockaddr *)&addr, sizeof addr) != 0) {
        snprintf(err, errlen, "socketcan: bind to '%s': %s", channel, strerror(errno));
        close(s);
        return -1;
    }
    bus->kind = HILBUS_SOCKETCAN;
    bus->sock = s;
    return 0;
}

void hilbus_socketcan_drops(const struct hilbus *bus, hilbus_stats_t *stats)
{
    /* The drop count the kernel stamps on received frames (SO_RXQ_OVFL) only reaches us
     * with the next frame; SO_MEMINFO reads the socket's counter directly. */
    uint32_t mem[SK_MEMINFO_VARS];
    socklen_t len = sizeof mem;
    if (getsockopt(bus->sock, SOL_SOCKET, SO_MEMINFO, mem, &len) == 0 && len > SK_MEMINFO_DROPS * sizeof mem[0]) {
        if (mem[SK_MEMINFO_DROPS] > stats->rx_overflows) stats->rx_overflows = mem[SK_MEMINFO_DROPS];
    }
}

int hilbus_socketcan_set_filters(struct hilbus *bus, const struct can_filter *filters, int n)
{
    /* SocketCAN: an empty filter list means "receive nothing", so n = 0 restores the default. */
    if (n == 0) {
        struct can_filter all = {.can_id = 0, .can_mask = 0};
        return setsockopt(bus->sock, SOL_CAN_RAW, CAN_RAW_FILTER, &all, sizeof all);
    }
    return setsockopt(bus->sock, SOL_CAN_RAW, CAN_RAW_FILTER, filters, (socklen_t)((size_t)n * sizeof *filters));
}

int hilbus_socketcan_send(struct hilbus *bus, const struct canfd_frame *frame, int fd)
{
    struct canfd_frame out = *frame;
    if (!fd) out.flags = 0;
    size_t size = fd ? CANFD_MTU : CAN_MTU;
    ssize_t n = send(bus->sock, &out, size, MSG_DONTWAIT);
    if (n == (ssize_t)size) return 0;
    if (n < 0 && (errno == ENOBUFS || errno == EAGAIN)) {
        bus->stats.tx_drops++; /* the interface queue is full: counted, as a full receiver */
        return 0;
    }
    bus->stats.tx_errors++;
    return -1;
}

int hilbus_socketcan_recv(struct hilbus *bus, struct canfd_frame *frame, int *fd)
{
    char control[CMSG_SPACE(sizeof(uint32_t))];
    struct iovec iov = {.iov_base = frame, .iov_len = sizeof *frame};
    struct msghdr msg;
    memset(&msg, 0, sizeof msg);
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof control;
    ssize_t n = recvmsg(bus->sock, &msg, MSG_DONTWAIT);
    if (n < 0) return (errno == EAGAIN || errno == EINTR) ? 0 : -1;
    for (struct cmsghdr *c = CMSG_FIRSTHDR(&msg); c != NULL; c = CMSG_NXTHDR(&msg, c)) {
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SO_RXQ_OVFL) {
            uint32_t total;
            memcpy(&total, CMSG_DATA(c), sizeof total);
            bus->stats.rx_overflows += (uint32_t)(total - bus->kernel_overflows);
            bus->kernel_overflows = total;
        }
    }
    if (n == CANFD_MTU) {
        *fd = 1;
        return 1;
    }
    if (n == CAN_MTU) {
        *fd = 0;
        frame->flags = 0;
        return 1;
    }
    return 0; /* not a CAN frame size: ignore */
}

/* hilbus over the userspace fallback bus "unixcan" (docs/interfaces.md).
 *
 * Every node of a channel binds a Unix datagram socket in the channel's directory and
 * sends each frame to every other socket there. Sends never block: a receiver whose queue
 * is full costs a counted drop, a socket nobody reads any more (a killed node) is removed. */
#define _GNU_SOURCE
#include <dirent.h>
#include <sched.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "hilbus_internal.h"

#define RESCAN_INTERVAL_NS 1000000000LL /* re-read membership at least once a second */
#define RECENT_CHANGE_NS 100000000LL    /* and on every send while the directory changed lately */
/* A receiving socket queues only net.unix.max_dgram_qlen datagrams (often 10), far fewer
 * than a SocketCAN socket buffer. A sender that finds a peer full waits this long for it
 * to drain before counting a drop; a peer still full after that is marked congested and
 * costs no further waiting until it accepts a frame again (a stopped node never slows
 * the bus down). */
#define FULL_PEER_GRACE_NS 2000000LL
#define CHECK_INTERVAL_NS 2000000LL /* look for joined or left nodes every 2 ms */

static int serial_counter;

static int64_t ts_ns(struct timespec t) { return (int64_t)t.tv_sec * 1000000000LL + t.tv_nsec; }

static int mkdir_p(const char *path)
{
    char tmp[sizeof(((struct sockaddr_un *)0)->sun_path)];
    size_t len = strlen(path);
    if (len >= sizeof tmp) {
        errno = ENAMETOOLONG;
        return -1;
    }
    memcpy(tmp, path, len + 1);
    for (char *p = tmp + 1; *p; p++) {
        if (*p == '/') {
            *p = '\0';
            if (mkdir(tmp, 0777) != 0 && errno != EEXIST) return -1;
            *p = '/';
        }
    }
    if (mkdir(tmp, 0777) != 0 && errno != EEXIST) return -1;
    return 0;
}

static int connect_peer(const struct sockaddr_un *addr)
{
    int s = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (s < 0) return -1;
    int buf = 4 << 20;
    (void)setsockopt(s, SOL_SOCKET, SO_SNDBUF, &buf, sizeof buf);
    if (connect(s, (const struct sockaddr *)addr, sizeof *addr) != 0) {
        close(s);
        return -1;
    }
    return s;
}

static void scan_peers(struct hilbus *bus)
{
    struct stat st;
    clock_gettime(CLOCK_REALTIME, &bus->last_scan);
    if (stat(bus->dir, &st) == 0) bus->dir_mtime = st.st_mtim;
    DIR *d = opendir(bus->dir);
    if (d == NULL) return;
    struct sockaddr_un found[HILBUS_MAX_PEERS];
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)) != NULL && n < HILBUS_MAX_PEERS) {
        size_t len = strlen(e->d_name);
        if (len < 6 || strcmp(e->d_name + len - 5, ".sock") != 0) continue;
        struct sockaddr_un *peer = &found[n];
        memset(peer, 0, sizeof *peer);
        peer->sun_family = AF_UNIX;
        int w = snprintf(peer->sun_path, sizeof peer->sun_path, "%s/%s", bus->dir, e->d_name);
        if (w < 0 || (size_t)w >= sizeof peer->sun_path) continue;
        if (strcmp(peer->sun_path, bus->self.sun_path) == 0) continue;
        n++;
    }
    closedir(d);
    /* Keep the connected sockets of peers still present; connect to new ones. */
    int fds[HILBUS_MAX_PEERS];
    unsigned char congested[HILBUS_MAX_PEERS];
    int m = 0;
    for (int i = 0; i < n; i++) {
        int fd = -1;
        unsigned char cong = 0;
        for (int j = 0; j < bus->n_peers; j++) {
            if (bus->peer_fd[j] >= 0 && strcmp(bus->peers[j].sun_path, found[i].sun_path) == 0) {
                fd = bus->peer_fd[j];
                cong = bus->congested[j];
                bus->peer_fd[j] = -1;
                break;
            }
        }
        if (fd < 0) fd = connect_peer(&found[i]);
        if (fd < 0) {
            /* Nobody reads that socket (a killed node): remove the stale file. */
            if (errno == ECONNREFUSED) {
                unlink(found[i].sun_path);
                bus->stats.peers_removed++;
            }
            continue;
        }
        found[m] = found[i];
        fds[m] = fd;
        congested[m] = cong;
        m++;
    }
    for (int j = 0; j < bus->n_peers; j++)
        if (bus->peer_fd[j] >= 0) close(bus->peer_fd[j]);
    memcpy(bus->peers, found, (size_t)m * sizeof found[0]);
    memcpy(bus->peer_fd, fds, (size_t)m * sizeof fds[0]);
    memcpy(bus->congested, congested, (size_t)m);
    bus->n_peers = m;
}

static int64_t mono_ns(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return ts_ns(t);
}

static void refresh_peers(struct hilbus *bus)
{
    /* clock_gettime is a vDSO call; stat() is a system call with a path lookup, so the
     * directory is looked at no more than every CHECK_INTERVAL_NS unless it changed lately. */
    int64_t mono = mono_ns();
    struct timespec now;
    clock_gettime(CLOCK_REALTIME, &now);
    int64_t since_scan = ts_ns(now) - ts_ns(bus->last_scan);
    /* Directory timestamps are coarse: keep re-reading while a change is recent, so a node
     * that joined within the same timestamp tick as our last scan is not missed. */
    if (since_scan > RESCAN_INTERVAL_NS || ts_ns(now) - ts_ns(bus->dir_mtime) < RECENT_CHANGE_NS) {
        scan_peers(bus);
        bus->last_check_ns = mono;
        return;
    }
    if (mono - bus->last_check_ns < CHECK_INTERVAL_NS) return;
    bus->last_check_ns = mono;
    struct stat st;
    if (stat(bus->dir, &st) == 0 && ts_ns(st.st_mtim) != ts_ns(bus->dir_mtime)) scan_peers(bus);
}

int hilbus_unixcan_open(struct hilbus *bus, const char *channel, char *err, size_t errlen)
{
    const char *base = getenv("UNIXCAN_DIR");
    if (base == NULL || base[0] == '\0') base = "/tmp/unixcan";
    int w = snprintf(bus->dir, sizeof bus->dir, "%s/%s", base, channel);
    if (w < 0 || (size_t)w >= sizeof bus->dir - 32) {
        snprintf(err, errlen, "unixcan: directory path '%s/%s' too long for a socket address", base, channel);
        return -1;
    }
    if (mkdir_p(bus->dir) != 0) {
        snprintf(err, errlen, "unixcan: cannot create %s: %s", bus->dir, strerror(errno));
        return -1;
    }
    int s = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (s < 0) {
        snprintf(err, errlen, "unixcan: socket: %s", strerror(errno));
        return -1;
    }
    int buf = 4 << 20;
    (void)setsockopt(s, SOL_SOCKET, SO_SNDBUF, &buf, sizeof buf);
    (void)setsockopt(s, SOL_SOCKET, SO_RCVBUF, &buf, sizeof buf);
    memset(&bus->self, 0, sizeof bus->self);
    bus->self.sun_family = AF_UNIX;
    char name[40];
    snprintf(name, sizeof name, "/%ld-%d.sock", (long)getpid(), serial_counter++);
    /* bus->dir leaves at least 24 bytes of sun_path (checked above); name is at most 30. */
    size_t dlen = strlen(bus->dir), nlen = strlen(name);
    if (dlen + nlen + 1 > sizeof bus->self.sun_path) {
        snprintf(err, errlen, "unixcan: socket path in %s too long", bus->dir);
        close(s);
        return -1;
    }
    memcpy(bus->self.sun_path, bus->dir, dlen);
    memcpy(bus->self.sun_path + dlen, name, nlen + 1);
    unlink(bus->self.sun_path);
    if (bind(s, (struct sockaddr *)&bus->self, sizeof bus->self) != 0) {
        snprintf(err, errlen, "unixcan: bind %s: %s", bus->self.sun_path, strerror(errno));
        close(s);
        return -1;
    }
    chmod(bus->self.sun_path, 0666);
    bus->kind = HILBUS_UNIXCAN;
    bus->sock = s;
    scan_peers(bus);
    return 0;
}

void hilbus_unixcan_close(struct hilbus *bus)
{
    for (int i = 0; i < bus->n_peers; i++)
        if (bus->peer_fd[i] >= 0) close(bus->peer_fd[i]);
    bus->n_peers = 0;
    unlink(bus->self.sun_path);
}

static void remove_peer(struct hilbus *bus, int i)
{
    /* Nobody reads this socket any more: its node died without cleaning up. */
    unlink(bus->peers[i].sun_path);
    close(bus->peer_fd[i]);
    bus->peers[i] = bus->peers[bus->n_peers - 1];
    bus->peer_fd[i] = bus->peer_fd[bus->n_peers - 1];
    bus->congested[i] = bus->congested[bus->n_peers - 1];
    bus->n_peers--;
    bus->stats.peers_removed++;
}

static ssize_t send_to_peer(struct hilbus *bus, int i, const struct canfd_frame *out, size_t size)
{
    ssize_t n = send(bus->peer_fd[i], out, size, MSG_DONTWAIT | MSG_NOSIGNAL);
    if (n >= 0 || (errno != EAGAIN && errno != EWOULDBLOCK) || bus->congested[i]) return n;
    const int64_t give_up = mono_ns() + FULL_PEER_GRACE_NS;
    do {
        sched_yield();
        n = send(bus->peer_fd[i], out, size, MSG_DONTWAIT | MSG_NOSIGNAL);
    } while (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK) && mono_ns() < give_up);
    return n;
}

int hilbus_unixcan_send(struct hilbus *bus, const struct canfd_frame *frame, int fd)
{
    struct canfd_frame out = *frame;
    if (!fd) out.flags = 0;
    size_t size = fd ? CANFD_MTU : CAN_MTU;
    refresh_peers(bus);
    for (int i = 0; i < bus->n_peers;) {
        ssize_t n = send_to_peer(bus, i, &out, size);
        if (n == (ssize_t)size) {
            bus->congested[i] = 0;
            i++;
        } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
            bus->stats.tx_drops++;
            bus->congested[i] = 1;
            i++;
        } else if (n < 0 && (errno == ECONNREFUSED || errno == ENOENT || errno == ENOTCONN)) {
            remove_peer(bus, i); /* the slot now holds another peer: do not advance */
        } else {
            bus->stats.tx_errors++;
            i++;
        }
    }
    return 0;
}

static int filters_pass(const struct hilbus *bus, canid_t id)
{
    if (bus->n_filters == 0) return 1;
    for (int i = 0; i < bus->n_filters; i++) {
        const struct can_filter *f = &bus->filters[i];
        if ((id & f->can_mask) == (f->can_id & f->can_mask)) return 1;
    }
    return 0;
}

int hilbus_unixcan_recv(struct hilbus *bus, struct canfd_frame *frame, int *fd)
{
    ssize_t n = recv(bus->sock, frame, sizeof *frame, MSG_DONTWAIT);
    if (n < 0) return (errno == EAGAIN || errno == EINTR) ? 0 : -1;
    if (n == CANFD_MTU) {
        *fd = 1;
    } else if (n == CAN_MTU) {
        *fd = 0;
        frame->flags = 0;
    } else {
        return 0; /* not a frame: ignore */
    }
    if (!filters_pass(bus, frame->can_id)) {
        bus->stats.rx_filtered++;
        return 0;
    }
    return 1;
}

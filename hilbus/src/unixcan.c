/* hilbus over the userspace fallback bus "unixcan" (docs/interfaces.md).
 *
 * Every node of a channel binds a Unix datagram socket in the channel's directory and
 * sends each frame to every other socket there. A node whose name carries the lossless mark
 * (the nodes of a lockstep run) is never dropped: a sender waits while its queue is full,
 * taking its own deliveries meanwhile (kept for hilbus_recv: two nodes waiting on each other
 * both go on), up to a bounded stall that ends in an error naming it. Any other node is a
 * listener: one whose queue is full costs a counted drop (per listener, by name); a socket
 * nobody reads any more (a killed node) is removed.
 * The wire (datagram layout, channel names, folder and socket naming and modes, the timing
 * nodes promise each other) is protocols/unixcan.toml, generated into hil_unixcan.h; the
 * rest of this file is hilbus's own way of being a node. */
#define _GNU_SOURCE
#include <dirent.h>
#include <poll.h>
#include <sched.h>
#include <errno.h>
#include <grp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "hilbus_internal.h"

/* hilbus's own: how it keeps the promise HIL_UNIXCAN_RESCAN_INTERVAL_NS (every node re-reads
 * the folder at least that often). Folder timestamps are coarse, so while the folder changed
 * less than RECENT_CHANGE_NS ago it is re-read on every send (a node that joined within the
 * timestamp tick of the last read is not missed); otherwise its timestamp is looked at no
 * more than every CHECK_INTERVAL_NS (stat() is a system call with a path lookup). */
#define RECENT_CHANGE_NS 100000000LL
#define CHECK_INTERVAL_NS 2000000LL
/* a wait for a lossless peer looks at the stop flag at least this often (a signal that sets
 * it also interrupts the wait) */
#define STOP_CHECK_MS 100
#define PENDING_FIRST 256

static int serial_counter;

static int64_t ts_ns(struct timespec t) { return (int64_t)t.tv_sec * 1000000000LL + t.tv_nsec; }

/* The directory rule (docs/interfaces.md; the names and modes are protocols/unixcan.toml):
 *  - base: $UNIXCAN_DIR, else $XDG_RUNTIME_DIR/unixcan (an absolute XDG_RUNTIME_DIR), else
 *    /tmp/unixcan-<uid>; the channel folder is base/<channel>, <channel> a plain name;
 *  - the folders above the base that exist must be trusted: each a directory of root or of
 *    this user that nobody else can write (a sticky one such as /tmp excepted, the group
 *    with UNIXCAN_GROUP), and a symbolic link among them one of root or of this user (so
 *    /var/run -> /run is fine, another user's link in /tmp is refused): nobody else can
 *    move the bus folder away or put another in its place;
 *  - what is missing is created with the folder mode (the group's, and group G, with
 *    UNIXCAN_GROUP=G);
 *  - the base and the channel folder must be real directories (a symlink is refused),
 *    owned by this user and writable by nobody else (the group only with UNIXCAN_GROUP);
 *    the channel folder's mode is then set to the folder mode: it holds only the bus's
 *    sockets;
 *  - sockets get the socket mode (the group's); only sockets owned by this user (or, with
 *    UNIXCAN_GROUP, of that group) are peers, and nothing else is ever removed. */
int hilbus_channel_name_ok(const char *channel)
{
    size_t n = channel ? strlen(channel) : 0;
    if (n == 0 || n > HIL_UNIXCAN_CHANNEL_MAX_LEN ||
        strchr(HIL_UNIXCAN_CHANNEL_NOT_FIRST, channel[0]) != NULL)
        return 0;
    return strspn(channel, HIL_UNIXCAN_CHANNEL_CHARS) == n;
}

static int lookup_group(gid_t *gid, char *err, size_t errlen)
{
    const char *name = getenv(HIL_UNIXCAN_GROUP_ENV);
    if (name == NULL || name[0] == '\0') return 0;
    struct group *g = getgrnam(name);
    if (g == NULL) {
        char *end = NULL;
        unsigned long v = strtoul(name, &end, 10);
        if (end == name || *end != '\0') {
            snprintf(err, errlen, "unixcan: %s=%s: no such group", HIL_UNIXCAN_GROUP_ENV, name);
            return -1;
        }
        *gid = (gid_t)v;
        return 1;
    }
    *gid = g->gr_gid;
    return 1;
}

int hilbus_unixcan_base(char *out, size_t outlen)
{
    const char *base = getenv(HIL_UNIXCAN_BASE_ENV);
    int w;
    if (base != NULL && base[0] != '\0') {
        w = snprintf(out, outlen, "%s", base);
    } else {
        const char *xdg = getenv(HIL_UNIXCAN_RUNTIME_ENV);
        struct stat st;
        if (xdg != NULL && xdg[0] == '/' && stat(xdg, &st) == 0 && S_ISDIR(st.st_mode))
            w = snprintf(out, outlen, "%s/%s", xdg, HIL_UNIXCAN_RUNTIME_SUBDIR);
        else
            w = snprintf(out, outlen, HIL_UNIXCAN_FALLBACK_BASE_FMT, (unsigned long)geteuid());
    }
    if (w < 0 || (size_t)w >= outlen) {
        errno = ENAMETOOLONG;
        return -1;
    }
    /* no trailing slashes: the socket paths are compared as strings */
    for (size_t n = strlen(out); n > 1 && out[n - 1] == '/'; n--) out[n - 1] = '\0';
    return 0;
}

/* Creates `path` if missing (mode `mode`), then checks it is ours (see the rule above). */
static int own_directory(const char *path, mode_t mode, int have_group, gid_t gid, int tighten,
                         char *err, size_t errlen)
{
    if (mkdir(path, mode) == 0) {
        if (have_group && chown(path, (uid_t)-1, gid) != 0) {
            snprintf(err, errlen, "unixcan: cannot give %s to group %lu: %s", path,
                     (unsigned long)gid, strerror(errno));
            return -1;
        }
        (void)chmod(path, mode); /* mkdir applies the umask */
    } else if (errno != EEXIST) {
        snprintf(err, errlen, "unixcan: cannot create %s: %s", path, strerror(errno));
        return -1;
    }
    struct stat st;
    if (lstat(path, &st) != 0) {
        snprintf(err, errlen, "unixcan: %s: %s", path, strerror(errno));
        return -1;
    }
    if (S_ISLNK(st.st_mode)) {
        snprintf(err, errlen, "unixcan: %s is a symbolic link; refused (the bus folder must be a "
                              "real directory)", path);
        return -1;
    }
    if (!S_ISDIR(st.st_mode)) {
        snprintf(err, errlen, "unixcan: %s is not a directory", path);
        return -1;
    }
    if (st.st_uid != geteuid()) {
        snprintf(err, errlen, "unixcan: %s belongs to uid %lu, not to this user (uid %lu); "
                              "refused (set UNIXCAN_DIR to a folder of your own)",
                 path, (unsigned long)st.st_uid, (unsigned long)geteuid());
        return -1;
    }
    mode_t foreign_write = have_group ? S_IWOTH : (S_IWGRP | S_IWOTH);
    if (have_group && st.st_gid != gid) foreign_write = S_IWGRP | S_IWOTH;
    if (tighten) {
        if ((st.st_mode & 07777) != mode && chmod(path, mode) != 0) {
            snprintf(err, errlen, "unixcan: cannot set mode %o on %s: %s", (unsigned)mode, path,
                     strerror(errno));
            return -1;
        }
        if (have_group && st.st_gid != gid && chown(path, (uid_t)-1, gid) != 0) {
            snprintf(err, errlen, "unixcan: cannot give %s to group %lu: %s", path,
                     (unsigned long)gid, strerror(errno));
            return -1;
        }
    } else if (st.st_mode & foreign_write) {
        snprintf(err, errlen, "unixcan: %s is writable by other users (mode %03o); refused "
                              "(chmod go-w it, or set UNIXCAN_DIR to a folder of your own)",
                 path, (unsigned)(st.st_mode & 0777));
        return -1;
    }
    return 0;
}

/* One existing folder above the base (see the rule above): 0 when trusted, 1 when it does
 * not exist (nor anything below it), -1 with a message when refused. */
static int trusted_parent(const char *path, int have_group, gid_t gid, char *err, size_t errlen)
{
    struct stat st;
    const uid_t me = geteuid();
    if (lstat(path, &st) != 0) {
        if (errno == ENOENT) return 1;
        snprintf(err, errlen, "unixcan: %s: %s", path, strerror(errno));
        return -1;
    }
    if (S_ISLNK(st.st_mode)) {
        if (st.st_uid != 0 && st.st_uid != me) {
            snprintf(err, errlen, "unixcan: %s (above the bus folder) is a symbolic link of uid %lu, "
                                  "neither root nor this user; refused (set UNIXCAN_DIR to a "
                                  "folder of your own)",
                     path, (unsigned long)st.st_uid);
            return -1;
        }
        if (stat(path, &st) != 0) {
            if (errno == ENOENT) return 1; /* a dangling link: mkdir below fails and says so */
            snprintf(err, errlen, "unixcan: %s: %s", path, strerror(errno));
            return -1;
        }
    }
    if (!S_ISDIR(st.st_mode)) {
        snprintf(err, errlen, "unixcan: %s (above the bus folder) is not a directory", path);
        return -1;
    }
    if (st.st_uid != 0 && st.st_uid != me) {
        snprintf(err, errlen, "unixcan: %s (above the bus folder) belongs to uid %lu, neither root "
                              "nor this user; refused (set UNIXCAN_DIR to a folder of your own)",
                 path, (unsigned long)st.st_uid);
        return -1;
    }
    if (!(st.st_mode & S_ISVTX) &&
        ((st.st_mode & S_IWOTH) || ((st.st_mode & S_IWGRP) && !(have_group && st.st_gid == gid)))) {
        snprintf(err, errlen, "unixcan: %s (above the bus folder) is writable by other users "
                              "(mode %03o); refused (set UNIXCAN_DIR to a folder of your own)",
                 path, (unsigned)(st.st_mode & 0777));
        return -1;
    }
    return 0;
}

/* The trusted parents checked, mkdir -p for the missing ones (the folder mode), then the base and
 * channel checks. */
static int make_bus_dir(struct hilbus *bus, const char *base, char *err, size_t errlen)
{
    gid_t gid = 0;
    int have_group = lookup_group(&gid, err, errlen);
    if (have_group < 0) return -1;
    const mode_t mode = have_group ? HIL_UNIXCAN_GROUP_FOLDER_MODE : HIL_UNIXCAN_FOLDER_MODE;
    char tmp[sizeof bus->dir];
    size_t len = strlen(base);
    if (len >= sizeof tmp) {
        snprintf(err, errlen, "unixcan: path %s too long", base);
        return -1;
    }
    memcpy(tmp, base, len + 1);
    int missing = 0; /* a folder above is missing: what is below it is made here */
    for (char *p = tmp + 1; *p; p++) {
        if (*p == '/') {
            *p = '\0';
            if (!missing) {
                const int t = trusted_parent(tmp, have_group, gid, err, errlen);
                if (t < 0) return -1;
                missing = t;
            }
            if (mkdir(tmp, HIL_UNIXCAN_FOLDER_MODE) != 0 && errno != EEXIST) {
                snprintf(err, errlen, "unixcan: cannot create %s: %s", tmp, strerror(errno));
                return -1;
            }
            *p = '/';
        }
    }
    if (own_directory(base, mode, have_group, gid, 0, err, errlen) != 0) return -1;
    if (own_directory(bus->dir, mode, have_group, gid, 1, err, errlen) != 0) return -1;
    bus->have_group = have_group;
    bus->group = gid;
    return 0;
}

/* A directory entry that may be a peer: a socket of ours (or of the bus's group). */
static int peer_entry_ok(const struct hilbus *bus, const char *path)
{
    struct stat st;
    if (lstat(path, &st) != 0 || !S_ISSOCK(st.st_mode)) return 0;
    if (st.st_uid == geteuid()) return 1;
    return bus->have_group && st.st_gid == bus->group;
}

/* Whether a socket's file name says its node loses no frame (HIL_UNIXCAN_LOSSLESS_MARK
 * before the suffix). */
static int lossless_name(const char *path)
{
    static const char tail[] = HIL_UNIXCAN_LOSSLESS_MARK HIL_UNIXCAN_SOCKET_SUFFIX;
    const size_t len = strlen(path), n = sizeof tail - 1;
    return len > n && strcmp(path + len - n, tail) == 0;
}

static const char *base_name(const char *path)
{
    const char *slash = strrchr(path, '/');
    return slash != NULL ? slash + 1 : path;
}

/* Whether a socket is the channel's bit clock (HIL_UNIXCAN_ARBITER, lossless: a sender waits
 * for the bus as a CAN controller does): while it is there, a classic frame goes to it alone
 * and a CAN FD frame to every other peer. */
static int arbiter_name(const char *path)
{
    return strcmp(base_name(path),
                  HIL_UNIXCAN_ARBITER HIL_UNIXCAN_LOSSLESS_MARK HIL_UNIXCAN_SOCKET_SUFFIX) == 0;
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
    int beyond = 0;
    while ((e = readdir(d)) != NULL) {
        const size_t len = strlen(e->d_name), suffix = sizeof HIL_UNIXCAN_SOCKET_SUFFIX - 1;
        if (len <= suffix || strcmp(e->d_name + len - suffix, HIL_UNIXCAN_SOCKET_SUFFIX) != 0) continue;
        struct sockaddr_un cand;
        memset(&cand, 0, sizeof cand);
        cand.sun_family = AF_UNIX;
        int w = snprintf(cand.sun_path, sizeof cand.sun_path, "%s/%s", bus->dir, e->d_name);
        if (w < 0 || (size_t)w >= sizeof cand.sun_path) continue;
        if (strcmp(cand.sun_path, bus->self.sun_path) == 0) continue;
        if (!peer_entry_ok(bus, cand.sun_path)) {
            bus->stats.foreign_entries++;
            continue;
        }
        if (n == HILBUS_MAX_PEERS) {
            beyond++; /* more nodes than a node can address: counted, reported by the programs */
            continue;
        }
        found[n++] = cand;
    }
    closedir(d);
    if ((uint64_t)beyond > bus->stats.peers_beyond_limit) bus->stats.peers_beyond_limit = (uint64_t)beyond;
    /* Keep the connected sockets of peers still present; connect to new ones. */
    int fds[HILBUS_MAX_PEERS];
    unsigned char congested[HILBUS_MAX_PEERS];
    unsigned char lossless[HILBUS_MAX_PEERS];
    unsigned char arbiter[HILBUS_MAX_PEERS];
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
        lossless[m] = (unsigned char)lossless_name(found[i].sun_path);
        arbiter[m] = (unsigned char)arbiter_name(found[i].sun_path);
        m++;
    }
    for (int j = 0; j < bus->n_peers; j++)
        if (bus->peer_fd[j] >= 0) close(bus->peer_fd[j]);
    memcpy(bus->peers, found, (size_t)m * sizeof found[0]);
    memcpy(bus->peer_fd, fds, (size_t)m * sizeof fds[0]);
    memcpy(bus->congested, congested, (size_t)m);
    memcpy(bus->lossless, lossless, (size_t)m);
    memcpy(bus->arbiter, arbiter, (size_t)m);
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
    if (since_scan > HIL_UNIXCAN_RESCAN_INTERVAL_NS ||
        ts_ns(now) - ts_ns(bus->dir_mtime) < RECENT_CHANGE_NS) {
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
    char base[sizeof bus->dir];
    if (hilbus_unixcan_base(base, sizeof base) != 0) {
        snprintf(err, errlen, "unixcan: UNIXCAN_DIR too long for a socket address");
        return -1;
    }
    int w = snprintf(bus->dir, sizeof bus->dir, "%s/%s", base, channel);
    if (w < 0 || (size_t)w >= sizeof bus->dir - 32) {
        snprintf(err, errlen, "unixcan: directory path '%s/%s' too long for a socket address", base, channel);
        return -1;
    }
    if (make_bus_dir(bus, base, err, errlen) != 0) return -1;
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
    char name[64];
    snprintf(name, sizeof name, "/%ld-" HIL_UNIXCAN_C_TAG "%d%s" HIL_UNIXCAN_SOCKET_SUFFIX, (long)getpid(),
             serial_counter++, (bus->flags & HILBUS_LOSSLESS) ? HIL_UNIXCAN_LOSSLESS_MARK : "");
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
    /* The folder is closed already; the socket's own mode says the same to whoever looks. */
    if (chmod(bus->self.sun_path,
              bus->have_group ? HIL_UNIXCAN_GROUP_SOCKET_MODE : HIL_UNIXCAN_SOCKET_MODE) != 0 ||
        (bus->have_group && chown(bus->self.sun_path, (uid_t)-1, bus->group) != 0)) {
        snprintf(err, errlen, "unixcan: cannot set the mode of %s: %s", bus->self.sun_path,
                 strerror(errno));
        close(s);
        unlink(bus->self.sun_path);
        return -1;
    }
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
    bus->lossless[i] = bus->lossless[bus->n_peers - 1];
    bus->arbiter[i] = bus->arbiter[bus->n_peers - 1];
    bus->n_peers--;
    bus->stats.peers_removed++;
}

/* Room for one more frame taken off the socket during a wait (grown on demand, at most
 * HILBUS_MAX_PENDING). */
static int pending_room(struct hilbus *bus)
{
    if (bus->pend_count < bus->pend_cap) return 1;
    if (bus->pend_cap >= HILBUS_MAX_PENDING) return 0;
    size_t cap = bus->pend_cap ? bus->pend_cap * 2 : PENDING_FIRST;
    struct hilbus_datagram *grown = malloc(cap * sizeof *grown);
    if (grown == NULL) return 0;
    for (size_t k = 0; k < bus->pend_count; k++)
        grown[k] = bus->pending[(bus->pend_head + k) % bus->pend_cap];
    free(bus->pending);
    bus->pending = grown;
    bus->pend_cap = cap;
    bus->pend_head = 0;
    return 1;
}

/* Takes what waits on this node's socket into the pending ring (while there is room). */
static void take_into_pending(struct hilbus *bus)
{
    while (pending_room(bus)) {
        struct hilbus_datagram *d = &bus->pending[(bus->pend_head + bus->pend_count) % bus->pend_cap];
        ssize_t n = recv(bus->sock, &d->frame, sizeof d->frame, MSG_DONTWAIT | MSG_TRUNC);
        if (n < 0) return;
        d->size = n > (ssize_t)INT_MAX ? INT_MAX : (int)n;
        bus->pend_count++;
        if (bus->pend_count > bus->stats.rx_pending_max) bus->stats.rx_pending_max = bus->pend_count;
    }
}

/* One try. To the bit clock from this node's own socket: it delivers the frame to every
 * node but its sender, so it must know who that is (the per-peer sockets have no name). */
static ssize_t send_once(struct hilbus *bus, int i, const struct canfd_frame *out, size_t size)
{
    if (bus->arbiter[i])
        return sendto(bus->sock, out, size, MSG_DONTWAIT | MSG_NOSIGNAL,
                      (const struct sockaddr *)&bus->peers[i], sizeof bus->peers[i]);
    return send(bus->peer_fd[i], out, size, MSG_DONTWAIT | MSG_NOSIGNAL);
}

/* A frame to a lossless peer whose queue was full: wait (taking this node's own deliveries
 * meanwhile) until it goes, the stop flag is set (EINTR) or HIL_UNIXCAN_LOSSLESS_STALL_NS
 * have passed (ETIMEDOUT). */
static ssize_t wait_for_lossless(struct hilbus *bus, int i, const struct canfd_frame *out, size_t size)
{
    const int64_t start = mono_ns(), give_up = start + HIL_UNIXCAN_LOSSLESS_STALL_NS;
    ssize_t n = -1;
    bus->stats.tx_stalls++;
    for (;;) {
        const int64_t now = mono_ns();
        if (bus->stop != NULL && *bus->stop) {
            errno = EINTR;
            break;
        }
        if (now >= give_up) {
            errno = ETIMEDOUT;
            break;
        }
        struct pollfd p[2] = {{.fd = bus->peer_fd[i], .events = POLLOUT, .revents = 0},
                              {.fd = bus->sock, .events = POLLIN, .revents = 0}};
        int64_t wait_ms = (give_up - now + 999999) / 1000000;
        if (wait_ms > STOP_CHECK_MS) wait_ms = STOP_CHECK_MS;
        const int np = pending_room(bus) ? 2 : 1;
        if (poll(p, (nfds_t)np, (int)wait_ms) > 0 && np == 2 && (p[1].revents & POLLIN))
            take_into_pending(bus);
        n = send_once(bus, i, out, size);
        if (n >= 0 || (errno != EAGAIN && errno != EWOULDBLOCK)) break;
    }
    const uint64_t waited = (uint64_t)(mono_ns() - start);
    bus->stats.tx_stall_ns_total += waited;
    if (waited > bus->stats.tx_stall_ns_max) bus->stats.tx_stall_ns_max = waited;
    return n;
}

static ssize_t send_to_peer(struct hilbus *bus, int i, const struct canfd_frame *out, size_t size)
{
    ssize_t n = send_once(bus, i, out, size);
    if (n >= 0 || (errno != EAGAIN && errno != EWOULDBLOCK)) return n;
    if (bus->lossless[i]) return wait_for_lossless(bus, i, out, size);
    if (bus->congested[i]) return n;
    const int64_t give_up = mono_ns() + HIL_UNIXCAN_FULL_PEER_GRACE_NS;
    do {
        sched_yield();
        n = send_once(bus, i, out, size);
    } while (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK) && mono_ns() < give_up);
    return n;
}

/* One more frame a listener missed, under its socket's name. */
static void note_listener_drop(struct hilbus *bus, int i)
{
    const char *name = base_name(bus->peers[i].sun_path);
    for (int k = 0; k < bus->n_listeners; k++) {
        if (strcmp(bus->listeners[k].name, name) == 0) {
            bus->listeners[k].drops++;
            return;
        }
    }
    if (bus->n_listeners < HILBUS_MAX_LISTENERS && strlen(name) < sizeof bus->listeners[0].name) {
        struct hilbus_listener_drops *l = &bus->listeners[bus->n_listeners++];
        memcpy(l->name, name, strlen(name) + 1);
        l->drops = 1;
        return;
    }
    bus->listener_drops_other++;
}

int hilbus_unixcan_send(struct hilbus *bus, const struct canfd_frame *frame, int fd)
{
    struct canfd_frame out = *frame;
    out.flags = fd ? (uint8_t)(out.flags | HIL_UNIXCAN_FDF) : 0; /* the wire's flags byte */
    size_t size = fd ? HIL_UNIXCAN_FD_SIZE : HIL_UNIXCAN_CLASSIC_SIZE;
    int failed = 0, clocked = 0;
    refresh_peers(bus);
    for (int i = 0; i < bus->n_peers; i++) clocked |= bus->arbiter[i];
    for (int i = 0; i < bus->n_peers;) {
        /* a bit clock on the channel: classic frames to it alone, CAN FD ones past it */
        if (clocked && bus->arbiter[i] != (unsigned char)!fd) {
            i++;
            continue;
        }
        ssize_t n = send_to_peer(bus, i, &out, size);
        if (n == (ssize_t)size) {
            bus->congested[i] = 0;
            i++;
        } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK) && !bus->lossless[i]) {
            bus->stats.tx_drops++;
            note_listener_drop(bus, i);
            bus->congested[i] = 1;
            i++;
        } else if (n < 0 && (errno == ECONNREFUSED || errno == ENOENT || errno == ENOTCONN)) {
            remove_peer(bus, i); /* the slot now holds another peer: do not advance */
        } else if (n < 0 && bus->lossless[i] && (errno == ETIMEDOUT || errno == EINTR)) {
            const char *dir = base_name(bus->dir), *peer = base_name(bus->peers[i].sun_path);
            if (errno == ETIMEDOUT) {
                bus->stats.tx_stall_failures++;
                snprintf(bus->last_error, sizeof bus->last_error,
                         "unixcan channel %s: node %s (pid %ld), which loses no frame, took none for "
                         "%lld ms (its queue stayed full): frame 0x%X not delivered to it",
                         dir, peer, strtol(peer, NULL, 10),
                         (long long)(HIL_UNIXCAN_LOSSLESS_STALL_NS / 1000000), (unsigned)frame->can_id);
                failed = ETIMEDOUT;
            } else {
                snprintf(bus->last_error, sizeof bus->last_error,
                         "unixcan channel %s: stopped while waiting for node %s", dir, peer);
                if (failed == 0) failed = EINTR;
            }
            i++;
        } else {
            bus->stats.tx_errors++;
            i++;
        }
    }
    if (failed != 0) {
        errno = failed;
        return -1;
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

/* The next datagram: one a send's wait took off the socket, else the socket's. */
static ssize_t next_datagram(struct hilbus *bus, struct canfd_frame *frame)
{
    if (bus->pend_count > 0) {
        const struct hilbus_datagram *d = &bus->pending[bus->pend_head];
        *frame = d->frame;
        bus->pend_head = (bus->pend_head + 1) % bus->pend_cap;
        bus->pend_count--;
        return d->size;
    }
    return recv(bus->sock, frame, sizeof *frame, MSG_DONTWAIT | MSG_TRUNC);
}

int hilbus_unixcan_recv(struct hilbus *bus, struct canfd_frame *frame, int *fd)
{
    /* MSG_TRUNC: the datagram's real size, so a longer one is not taken for a frame */
    ssize_t n = next_datagram(bus, frame);
    if (n < 0) return (errno == EAGAIN || errno == EINTR) ? 0 : -1;
    if (n == HIL_UNIXCAN_FD_SIZE) {
        *fd = 1;
    } else if (n == HIL_UNIXCAN_CLASSIC_SIZE) {
        *fd = 0;
        frame->flags = 0;
    } else {
        bus->stats.rx_malformed++; /* neither a struct can_frame nor a struct canfd_frame */
        return 0;
    }
    if (frame->len > (*fd ? HIL_UNIXCAN_FD_MAX_LEN : HIL_UNIXCAN_CLASSIC_MAX_LEN) ||
        (*fd && hilbus_fd_len(frame->len) != frame->len)) {
        bus->stats.rx_malformed++; /* a length no CAN controller sends: never handed on */
        return 0;
    }
    if (!filters_pass(bus, frame->can_id)) {
        bus->stats.rx_filtered++;
        return 0;
    }
    return 1;
}

// The Store's plumbing: opening the file, the connections (one writer, a read pool, the
// checkpointer) and the background WAL checkpoints. Each table's calls are in store_<table>.cc.
#include "storage/store.h"

#include <algorithm>
#include <chrono>
#include <random>
#include <thread>
#include <utility>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "storage/migrations.h"
#include "storage/pg_db.h"
#include "storage/status_macros.h"
#include "storage/store_internal.h"
#include "util/db.h"
#include "util/sqlite_db.h"
#include "util/str_util.h"

namespace imucal::storage {

Store::Store(StoreOptions options, std::unique_ptr<sql::Connection> writer,
             std::unique_ptr<sql::SqliteConnection> checkpointer,
             std::vector<std::unique_ptr<sql::Connection>> readers)
    : options_(std::move(options)),
      writer_(std::move(writer)),
      checkpointer_(std::move(checkpointer)),
      readers_(std::move(readers)) {
  for (const auto& r : readers_) free_readers_.push_back(r.get());
  writer_->on_transaction = options_.on_transaction;
}

Store::~Store() {
  listener_.reset();  // no more callbacks into the caller
  {
    std::lock_guard lock(commit_mu_);
    stopping_ = true;
  }
  commit_cv_.notify_all();
  checkpoint_cv_.notify_all();
  if (committer_.joinable()) committer_.join();  // after every submitted batch
  if (checkpoint_thread_.joinable()) checkpoint_thread_.join();
  checkpointer_.reset();  // before the writer, which checkpoints as the last one out
}

absl::StatusOr<std::unique_ptr<Store>> Store::Open(const std::string& path, StoreOptions options) {
  if (path.empty() || path == ":memory:") {
    return absl::InvalidArgumentError("Store::Open needs a file path (connections share it)");
  }
  if (options.read_connections < 1) {
    return absl::InvalidArgumentError("StoreOptions::read_connections must be at least 1");
  }
  if (absl::Status s = sql::CheckLocation(path); !s.ok()) return s;
  if (sql::IsPostgresUrl(path)) return OpenPostgres(path, std::move(options));
  const std::string op = Cat("open ", path);
  sql::ConnectionOptions conn_options;
  conn_options.synchronous_full = options.durability == Durability::kFull;
  conn_options.busy_timeout = options.busy_timeout;
  IMUCAL_ASSIGN_OR_RETURN(std::unique_ptr<sql::Connection> writer,
                          Annotate(op, sql::SqliteConnection::Open(path, conn_options)));
  {
    // WAL is a property of the file: set once, kept by every later open.
    IMUCAL_ASSIGN_OR_RETURN(
        std::optional<std::string> mode,
        Annotate(op, sql::ReadRow(*writer, "PRAGMA journal_mode = WAL", sql::FirstColumnText)));
    if (mode.value_or("") != "wal") {
      return absl::FailedPreconditionError(
          Cat(op, ": cannot switch to WAL (journal mode is '", mode.value_or(""), "')"));
    }
  }
  // After a checkpoint, cut the -wal file back to 64 MiB instead of leaving it at the size an
  // ingest burst grew it to.
  IMUCAL_RETURN_IF_ERROR(Annotate(op, writer->Exec("PRAGMA journal_size_limit = 67108864")));
  IMUCAL_RETURN_IF_ERROR(Annotate(op, Migrate(*writer)));
  IMUCAL_ASSIGN_OR_RETURN(std::unique_ptr<sql::SqliteConnection> checkpointer,
                          Annotate(op, sql::SqliteConnection::Open(path, conn_options)));
  std::vector<std::unique_ptr<sql::Connection>> readers;
  conn_options.read_only = true;
  for (int i = 0; i < options.read_connections; ++i) {
    IMUCAL_ASSIGN_OR_RETURN(std::unique_ptr<sql::Connection> reader,
                            Annotate(op, sql::SqliteConnection::Open(path, conn_options)));
    readers.push_back(std::move(reader));
  }
  std::unique_ptr<Store> store(new Store(std::move(options), std::move(writer),
                                        std::move(checkpointer), std::move(readers)));
  store->location_ = path;
  return store;
}

namespace {

// A store's name in the session notifications it sends: random, so that two stores (two
// servers, or a server and a tool) never share one.
std::string RandomOrigin() {
  std::random_device device;
  std::mt19937_64 rng((uint64_t{device()} << 32) ^ device());
  return absl::StrCat("s", absl::Hex(rng(), absl::kZeroPad16));
}

}  // namespace

absl::StatusOr<std::unique_ptr<Store>> Store::OpenPostgres(const std::string& url,
                                                           StoreOptions options) {
  // PostgreSQL keeps its own write-ahead log and checkpoints: no checkpointer. Commits are
  // synchronous whatever options.durability says (pg_db.h).
  // A connection's error names the URL already ("cannot connect to URL: ..."): "open" only.
  const std::string op = Cat("open ", sql::RedactedLocation(url));
  sql::ConnectionOptions conn_options;
  conn_options.busy_timeout = options.busy_timeout;
  conn_options.origin = RandomOrigin();
  IMUCAL_ASSIGN_OR_RETURN(std::unique_ptr<sql::Connection> writer,
                          Annotate("open", PgConnection::Open(url, conn_options)));
  IMUCAL_RETURN_IF_ERROR(Annotate(op, Migrate(*writer)));
  std::vector<std::unique_ptr<sql::Connection>> readers;
  conn_options.read_only = true;
  for (int i = 0; i < options.read_connections; ++i) {
    IMUCAL_ASSIGN_OR_RETURN(std::unique_ptr<sql::Connection> reader,
                            Annotate("open", PgConnection::Open(url, conn_options)));
    readers.push_back(std::move(reader));
  }
  std::unique_ptr<Store> store(
      new Store(std::move(options), std::move(writer), nullptr, std::move(readers)));
  store->location_ = url;
  store->origin_ = conn_options.origin;
  return store;
}

absl::Status Store::ListenForChanges(ChangeHandlers handlers) {
  if (dialect() != sql::Dialect::kPostgres) {
    return absl::FailedPreconditionError(
        "ListenForChanges: only on PostgreSQL (SQLite: ActiveChangesSince)");
  }
  if (listener_ != nullptr) {
    return absl::FailedPreconditionError("ListenForChanges: already listening");
  }
  absl::StatusOr<std::unique_ptr<PgListener>> listener = PgListener::Start(
      location_, {kActiveChannel, kSessionChannel, kTokenChannel},
      [h = handlers, origin = origin_](std::string_view channel, std::string_view payload) {
        if (channel == kActiveChannel) {
          if (h.on_active) h.on_active(payload);
          return;
        }
        if (channel == kTokenChannel) {
          int64_t id = 0;
          if (h.on_token && absl::SimpleAtoi(absl::string_view(payload.data(), payload.size()), &id))
            h.on_token(id);
          return;
        }
        // "<origin> <session id>": this store's own commits are not news to it.
        const size_t space = payload.find(' ');
        if (space == std::string_view::npos || payload.substr(0, space) == origin) return;
        if (h.on_session) h.on_session(payload.substr(space + 1));
      },
      [h = handlers] {
        if (h.on_gap) h.on_gap();
      });
  if (!listener.ok()) return listener.status();
  listener_ = *std::move(listener);
  return absl::OkStatus();
}

void Store::StopListening() { listener_.reset(); }

sql::Dialect Store::dialect() const { return writer_->dialect(); }

absl::Status Store::Ping() {
  ReadLease lease = AcquireReader();
  return Annotate("Ping", lease.conn().Exec("SELECT 1"));
}

void PauseBeforeRetry(int attempt) {
  thread_local std::mt19937_64 rng{std::random_device{}()};
  const int64_t max_us = int64_t{1000} << std::min(attempt, 8);
  std::this_thread::sleep_for(std::chrono::microseconds(
      std::uniform_int_distribution<int64_t>(max_us / 4, max_us)(rng)));
}

absl::StatusOr<ParamVersion> Store::NotifyIfActive(absl::StatusOr<ParamVersion> version) {
  if (version.ok() && version->state == VersionState::kActive && options_.on_active_change)
    options_.on_active_change(version->device_id);
  return version;
}

absl::Time Store::Now() const {
  // Microseconds, as stored, so a returned object equals the one read back later.
  return FromMicros(Micros(options_.clock ? options_.clock() : absl::Now()));
}

// ---- The read pool ---------------------------------------------------------------------------

Store::ReadLease Store::AcquireReader() {
  std::unique_lock lock(readers_mu_);
  reader_free_.wait(lock, [this] { return !free_readers_.empty(); });
  sql::Connection* conn = free_readers_.back();
  free_readers_.pop_back();
  return ReadLease(this, conn);
}

void Store::ReleaseReader(sql::Connection* conn) {
  {
    std::lock_guard lock(readers_mu_);
    free_readers_.push_back(conn);
  }
  reader_free_.notify_one();
}

// ---- Background threads: the committer (CommitLoop, store_samples.cc) and checkpoints ------

void Store::StartBackgroundThreads() {
  committer_ = std::thread([this] { CommitLoop(); });
  if (checkpointer_ == nullptr) return;  // PostgreSQL checkpoints by itself
  {
    // From now on the writer's commits no longer checkpoint (SQLite's automatic checkpoint is
    // this hook): count the WAL's pages and let CheckpointLoop do it.
    std::lock_guard lock(write_mu_);
    sqlite3_wal_hook(
        static_cast<sql::SqliteConnection&>(*writer_).db(),
        [](void* arg, sqlite3*, const char*, int pages) {
          Store* store = static_cast<Store*>(arg);
          store->wal_pages_.store(pages, std::memory_order_relaxed);
          if (pages >= kCheckpointPages) store->checkpoint_cv_.notify_one();
          return SQLITE_OK;
        },
        this);
  }
  checkpoint_thread_ = std::thread([this] { CheckpointLoop(); });
}

void Store::CheckpointLoop() {
  // WAL checkpoints off the commit path: the writer's automatic checkpoint (which would run
  // inside a commit, holding up every stream's ack) is off; this thread copies the WAL into
  // the database with PASSIVE checkpoints (never blocking the writer or readers) on its own
  // connection, when the WAL has grown by kCheckpointPages or every second.
  std::unique_lock lock(commit_mu_);
  while (!stopping_) {
    checkpoint_cv_.wait_for(lock, std::chrono::seconds(1), [this] {
      return stopping_ || wal_pages_.load(std::memory_order_relaxed) >= kCheckpointPages;
    });
    if (stopping_) return;
    if (wal_pages_.load(std::memory_order_relaxed) == 0) continue;
    lock.unlock();
    wal_pages_.store(0, std::memory_order_relaxed);
    // Best effort: a busy or failed checkpoint is retried at the next round.
    (void)sqlite3_wal_checkpoint_v2(checkpointer_->db(), nullptr, SQLITE_CHECKPOINT_PASSIVE,
                                    nullptr, nullptr);
    lock.lock();
  }
}

}  // namespace imucal::storage

%% @doc Internal. The promises this node's voter gave (one
%% `evatar_ha_core:record()' per pairing), on disc in the data directory
%% (mnesia's, `EVATAR_DATA_DIR'), so that a node killed and booted again
%% still refuses what it promised to another instance, as Raft keeps its
%% vote. `evatar_cluster' writes each changed record with {@link write/2},
%% which returns once the bytes are on the device (fdatasync), before the
%% grant is sent, and reads them back at boot with {@link open/1}. Without
%% a data directory (`make demo', most suites) the promises live in memory
%% as long as the node does.
%%
%% The file, `ha_promises.log', is a log of frames
%% `<<Size:32, Crc32:32, term_to_binary({PairingId, Record})>>'; the last
%% frame of a pairing wins. A frame cut short or corrupt (a power loss in
%% the middle of a write, a write refused for a full disk) ends the log: it
%% is dropped at boot, and a write always starts where the last good frame
%% ended. Once it holds four times as many frames as there are pairings
%% (and at least 1,024), it is rewritten with one frame each, to a new file
%% synced before it is renamed over the old one. The file is this node's
%% own, written by this module only, and read as such.
-module(evatar_ha_promises).

-export([open/1, write/2, compact/2, needs_compaction/2, dir/0]).

-export_type([log/0]).

-define(LOG_FILE, "ha_promises.log").

-record(log, {path :: file:filename() | undefined,
              fd :: file:io_device() | undefined,
              %% Where the next frame goes: the end of the last good one.
              offset = 0 :: non_neg_integer(),
              frames = 0 :: non_neg_integer()}).
-opaque log() :: #log{}.

-type entry() :: {term(), evatar_ha_core:record()}.

%% @doc The data directory promises are kept in: mnesia's, when the node
%% has one.
-spec dir() -> file:filename() | undefined.
dir() ->
    case application:get_env(mnesia, dir) of
        {ok, Dir} -> Dir;
        undefined -> undefined
    end.

%% @doc Opens the log in `Dir' (made if missing, readable by this node's
%% user only) and reads the promises back; `undefined' keeps them in
%% memory. An error (the file unreadable, the directory not to be made)
%% means no promise can be kept: the caller grants nothing until a later
%% open succeeds.
-spec open(file:filename() | undefined) -> {ok, log(), [entry()]} | {error, term()}.
open(undefined) ->
    {ok, #log{}, []};
open(Dir) ->
    Path = filename:join(Dir, ?LOG_FILE),
    case evatar_data_dir:ensure(Dir) of
        ok ->
            case file:open(Path, [raw, binary, read, write]) of
                {ok, Fd} -> load(Fd, Path);
                {error, _} = Error -> Error
            end;
        {error, _} = Error ->
            Error
    end.

load(Fd, Path) ->
    case read_all(Fd) of
        {ok, Bin} ->
            {Entries, Good, Frames} = frames(Bin, 0, 0, #{}),
            %% A torn tail goes now, so that nothing written later hides
            %% behind it.
            case {file:position(Fd, Good), file:truncate(Fd)} of
                {{ok, Good}, ok} ->
                    {ok, #log{path = Path, fd = Fd, offset = Good, frames = Frames},
                     maps:to_list(Entries)};
                {_, Error} ->
                    _ = file:close(Fd),
                    {error, Error}
            end;
        {error, _} = Error ->
            _ = file:close(Fd),
            Error
    end.

read_all(Fd) ->
    read_all(Fd, []).

read_all(Fd, Acc) ->
    case file:read(Fd, 1 bsl 20) of
        {ok, Bin} -> read_all(Fd, [Bin | Acc]);
        eof -> {ok, iolist_to_binary(lists:reverse(Acc))};
        {error, _} = Error -> Error
    end.

frames(<<Size:32, Crc:32, Payload:Size/binary, Rest/binary>>, Good, N, Acc) ->
    case erlang:crc32(Payload) of
        Crc ->
            {Id, Record} = binary_to_term(Payload),
            frames(Rest, Good + 8 + Size, N + 1, Acc#{Id => Record});
        _ ->
            {Acc, Good, N}
    end;
frames(_Torn, Good, N, Acc) ->
    {Acc, Good, N}.

frame(Entry) ->
    Payload = term_to_binary(Entry),
    [<<(byte_size(Payload)):32, (erlang:crc32(Payload)):32>>, Payload].

%% @doc Writes the records and returns once they are on the device.
%% `{error, Reason, Log}': none of them may be counted on (a frame cut
%% short is overwritten by the next write).
-spec write(log(), [entry()]) -> {ok, log()} | {error, term(), log()}.
write(#log{path = undefined} = L, _Entries) ->
    {ok, L};
write(L, []) ->
    {ok, L};
write(#log{fd = Fd, offset = Off, frames = N} = L, Entries) ->
    Data = iolist_to_binary([frame(E) || E <- Entries]),
    case file:pwrite(Fd, Off, Data) of
        ok ->
            case file:datasync(Fd) of
                ok -> {ok, L#log{offset = Off + byte_size(Data), frames = N + length(Entries)}};
                {error, Reason} -> {error, Reason, L}
            end;
        {error, Reason} ->
            {error, Reason, L}
    end.

%% @doc Whether the log holds enough superseded frames, with `Live'
%% pairings, to be worth rewriting.
-spec needs_compaction(log(), non_neg_integer()) -> boolean().
needs_compaction(#log{path = undefined}, _Live) -> false;
needs_compaction(#log{frames = N}, Live) -> N >= max(1024, 4 * Live).

%% @doc Rewrites the log with `Entries' (every pairing's record) only. A
%% failure leaves the old log in use; it holds the same promises.
-spec compact(log(), [entry()]) -> {ok, log()} | {error, term(), log()}.
compact(#log{path = undefined} = L, _Entries) ->
    {ok, L};
compact(#log{path = Path, fd = Old} = L, Entries) ->
    Tmp = Path ++ ".new",
    Data = iolist_to_binary([frame(E) || E <- Entries]),
    case write_synced(Tmp, Data) of
        ok ->
            case file:rename(Tmp, Path) of
                ok ->
                    _ = file:close(Old),
                    {ok, Fd} = file:open(Path, [raw, binary, read, write]),
                    {ok, L#log{fd = Fd, offset = byte_size(Data), frames = length(Entries)}};
                {error, Reason} ->
                    _ = file:delete(Tmp),
                    {error, Reason, L}
            end;
        {error, Reason} ->
            _ = file:delete(Tmp),
            {error, Reason, L}
    end.

write_synced(Path, Data) ->
    case file:open(Path, [raw, binary, write]) of
        {ok, Fd} ->
            R = case file:write(Fd, Data) of
                    ok -> file:sync(Fd);
                    {error, _} = E -> E
                end,
            _ = file:close(Fd),
            R;
        {error, _} = Error ->
            Error
    end.

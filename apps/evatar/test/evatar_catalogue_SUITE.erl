%% Common Test suite of the catalogue's data directory (EVATAR_DATA_DIR,
%% mnesia's directory), each case on a fresh node started with OTP's peer:
%% a directory whose parents are missing is made, private to the node's
%% user; one that cannot be made stops evatar with an error naming it.
-module(evatar_catalogue_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("kernel/include/file.hrl").

-export([all/0, suite/0, data_dir_is_made_private/1, unusable_data_dir_stops/1]).

suite() -> [{timetrap, {minutes, 2}}].

all() -> [data_dir_is_made_private, unusable_data_dir_stops].

%% A data directory two levels below anything that exists is made, with
%% mode 0700, and the catalogue is durable in it.
data_dir_is_made_private(Config) ->
    Dir = filename:join([?config(priv_dir, Config), "absent", "parents", "data"]),
    with_node(Dir, fun(Peer) ->
                           {ok, _} = peer:call(Peer, application, ensure_all_started, [evatar]),
                           true = peer:call(Peer, evatar_catalogue, durable, []),
                           {ok, _} = peer:call(Peer, evatar, create_pairing,
                                               [<<"kept">>, #{agent_credential => <<"a">>,
                                                              avatar_credential => <<"b">>}]),
                           {ok, #file_info{type = directory, mode = Mode}} =
                               file:read_file_info(Dir),
                           8#700 = Mode band 8#777,
                           true = filelib:is_regular(filename:join(Dir, "schema.DAT"))
                   end).

%% A data directory below a regular file cannot be made: evatar does not
%% start, and the reason names the directory.
unusable_data_dir_stops(Config) ->
    File = filename:join(?config(priv_dir, Config), "a-file"),
    ok = file:write_file(File, <<"not a directory">>),
    Dir = filename:join(File, "data"),
    with_node(Dir, fun(Peer) ->
                           {error, Why} = peer:call(Peer, application, ensure_all_started,
                                                    [evatar]),
                           ct:log("~p", [Why]),
                           Text = lists:flatten(io_lib:format("~p", [Why])),
                           true = string:find(Text, "data_dir_unusable") =/= nomatch,
                           true = string:find(Text, Dir) =/= nomatch
                   end).

with_node(Dir, Fun) ->
    Paths = lists:append([["-pa", P] || P <- code:get_path()]),
    {ok, Peer, _Node} = peer:start_link(#{connection => standard_io,
                                          args => ["-mnesia", "dir", "\"" ++ Dir ++ "\""
                                                   | Paths]}),
    try Fun(Peer)
    after peer:stop(Peer)
    end.

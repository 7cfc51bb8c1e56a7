%% @doc Internal. Small real PNG images (8-bit RGB, zlib from OTP): the
%% simulated camera's photos, drawing a room, its light, and a figure for
%% each person in it, with the time as a row of bits so no two photos of the
%% same scene are the same file.
-module(avatar_sim_png).

-export([encode/3, photo/4]).

-type rgb() :: {byte(), byte(), byte()}.

-define(W, 64).
-define(H, 48).

%% @doc A PNG file of `W' x `H' pixels; `Pixel(X, Y)' gives each colour.
-spec encode(pos_integer(), pos_integer(), fun((non_neg_integer(), non_neg_integer()) -> rgb()))
            -> binary().
encode(W, H, Pixel) ->
    Raw = << <<0, (row(W, Y, Pixel))/binary>> || Y <- lists:seq(0, H - 1) >>,
    iolist_to_binary([<<137, $P, $N, $G, 13, 10, 26, 10>>,
                      chunk(<<"IHDR">>, <<W:32, H:32, 8, 2, 0, 0, 0>>),
                      chunk(<<"IDAT">>, zlib:compress(Raw)),
                      chunk(<<"IEND">>, <<>>)]).

row(W, Y, Pixel) ->
    << <<R, G, B>> || X <- lists:seq(0, W - 1), {R, G, B} <- [Pixel(X, Y)] >>.

chunk(Type, Data) ->
    [<<(byte_size(Data)):32>>, Type, Data, <<(erlang:crc32([Type, Data])):32>>].

%% @doc A 64 x 48 photo of `Room' with its light on or off and `People'
%% (`resident', `intruder' or anyone else) in it, taken at `TimeMs'.
-spec photo(binary(), boolean(), [binary()], integer()) -> binary().
photo(Room, Lit, People, TimeMs) ->
    Wall = shade(room_colour(Room), Lit),
    Floor = shade({110, 80, 50}, Lit),
    Figures = lists:zip(lists:seq(0, length(People) - 1), People),
    Bits = TimeMs div 1000,
    encode(?W, ?H,
           fun(X, 0) ->
                   case (Bits bsr (X rem 32)) band 1 of
                       1 -> {255, 255, 255};
                       0 -> {0, 0, 0}
                   end;
              (X, Y) ->
                   case figure(X, Y, Figures) of
                       {ok, C} -> shade(C, true);
                       none when Y >= 36 -> Floor;
                       none -> Wall
                   end
           end).

figure(_X, _Y, []) -> none;
figure(X, Y, [{I, Who} | Rest]) ->
    Left = 8 + I * 14,
    Head = X >= Left + 2 andalso X < Left + 7 andalso Y >= 14 andalso Y < 19,
    Body = X >= Left andalso X < Left + 9 andalso Y >= 19 andalso Y < 40,
    case Head orelse Body of
        true -> {ok, person_colour(Who)};
        false -> figure(X, Y, Rest)
    end.

person_colour(<<"intruder">>) -> {200, 30, 30};
person_colour(<<"resident">>) -> {40, 80, 200};
person_colour(_) -> {40, 160, 60}.

room_colour(<<"hall">>) -> {200, 190, 160};
room_colour(<<"living">>) -> {180, 200, 170};
room_colour(<<"kitchen">>) -> {220, 220, 200};
room_colour(<<"bedroom">>) -> {190, 170, 200};
room_colour(_) -> {180, 180, 180}.

shade(C, true) -> C;
shade({R, G, B}, false) -> {R div 5, G div 5, B div 5}.
